#include "core/matrix/ifs_matrix_core.h"

#include <algorithm>
#include <string>
#include <utility>

#include "absl/strings/str_cat.h"
#include "core/matrix/matrix_text.h"

namespace nimbus {

using matrix_internal::CellText;
using matrix_internal::Quoted;

// ---------------------------------------------------------------------------
// IfsMatrix / BoolMatrix

absl::StatusOr<IfsMatrix> IfsMatrix::FromRows(const std::vector<std::vector<Entry>>& rows) {
  const uint32_t n = static_cast<uint32_t>(rows.size());
  IfsMatrix m(n);
  for (uint32_t i = 0; i < n; ++i) {
    if (rows[i].size() != n)
      return absl::InvalidArgumentError(
          absl::StrCat("IFS matrix row ", i, " has ", rows[i].size(), " entries, expected ", n));
    for (uint32_t j = 0; j < n; ++j) m.Set(i, j, rows[i][j]);
  }
  return m;
}

void IfsMatrix::Set(uint32_t i, uint32_t j, Entry maps) {
  std::sort(maps.begin(), maps.end());
  maps.erase(std::unique(maps.begin(), maps.end()), maps.end());
  entries_[size_t{i} * n_ + j] = std::move(maps);
}

void IfsMatrix::Insert(uint32_t i, uint32_t j, uint32_t map) {
  Entry& e = entries_[size_t{i} * n_ + j];
  auto it = std::lower_bound(e.begin(), e.end(), map);
  if (it == e.end() || *it != map) e.insert(it, map);
}

uint64_t IfsMatrix::MapReferences() const {
  uint64_t total = 0;
  for (const Entry& e : entries_) total += e.size();
  return total;
}

absl::Status ValidateMatrix(const IfsMatrix& m, size_t table_size, std::string_view name) {
  for (uint32_t i = 0; i < m.size(); ++i)
    for (uint32_t j = 0; j < m.size(); ++j)
      for (uint32_t f : m.at(i, j))
        if (f >= table_size)
          return absl::InvalidArgumentError(
              absl::StrCat("IFS matrix ", Quoted(name), " entry ", CellText(i, j),
                           " refers to map ", f, ", but the table has ", table_size, " maps"));
  return absl::OkStatus();
}

BoolMatrix BoolMatrix::PatternOf(const IfsMatrix& m) {
  BoolMatrix r(m.size());
  for (uint32_t i = 0; i < m.size(); ++i)
    for (uint32_t j = 0; j < m.size(); ++j)
      if (!m.empty(i, j)) r.Set(i, j);
  return r;
}

void BoolMatrix::Set(uint32_t i, uint32_t j, bool v) {
  uint64_t& w = bits_[size_t{i} * words_ + j / 64];
  const uint64_t bit = uint64_t{1} << (j % 64);
  w = v ? (w | bit) : (w & ~bit);
}

BoolMatrix operator*(const BoolMatrix& a, const BoolMatrix& b) {
  BoolMatrix c(a.n_);
  const uint32_t w = a.words_;
  for (uint32_t i = 0; i < a.n_; ++i) {
    uint64_t* out = &c.bits_[size_t{i} * w];
    for (uint32_t k = 0; k < a.n_; ++k) {
      if (!a.Get(i, k)) continue;
      const uint64_t* row = &b.bits_[size_t{k} * w];
      for (uint32_t x = 0; x < w; ++x) out[x] |= row[x];
    }
  }
  return c;
}

// ---------------------------------------------------------------------------
// Aperiodicity

PowerAnalysis AnalyzePowers(const BoolMatrix& r) {
  PowerAnalysis out;
  const uint32_t n = r.size();
  if (n == 0) {
    out.limit = r;
    out.index = 1;
    return out;
  }
  // squares[b] = R^(2^b), enough bits to reach K.
  const uint64_t k = uint64_t{n} * n + 1;
  std::vector<BoolMatrix> squares{r};
  while ((uint64_t{1} << squares.size()) <= k) squares.push_back(squares.back() * squares.back());
  BoolMatrix rk;
  bool have = false;
  for (size_t b = 0; b < squares.size(); ++b) {
    if (!((k >> b) & 1)) continue;
    rk = have ? rk * squares[b] : squares[b];
    have = true;
  }
  const BoolMatrix next = rk * r;
  if (next == rk) {
    out.limit = rk;
    out.period = 1;
    // R^m == R^(m+1) is monotone in m: binary lifting finds the last m where
    // it fails; the index is one more.
    if (r * r == r) {
      out.index = 1;
    } else {
      BoolMatrix cur = r;
      uint64_t e = 1;
      for (size_t b = squares.size(); b-- > 0;) {
        if (e + (uint64_t{1} << b) > k) continue;
        BoolMatrix cand = cur * squares[b];
        if (!(cand * r == cand)) {
          cur = std::move(cand);
          e += uint64_t{1} << b;
        }
      }
      out.index = e + 1;
    }
    return out;
  }
  // On the cycle: its length is the first return to R^K.
  constexpr uint64_t kPeriodCap = 4096;
  BoolMatrix p = next;
  uint64_t t = 1;
  while (!(p == rk) && t < kPeriodCap) {
    p = p * r;
    ++t;
  }
  out.limit = rk;
  out.index = 0;
  out.period = (p == rk) ? t : 0;
  return out;
}

absl::StatusOr<BoolMatrix> AperiodicLimitPattern(const IfsMatrix& m, std::string_view name) {
  if (m.size() == 0)
    return absl::InvalidArgumentError(absl::StrCat("IFS matrix ", Quoted(name), " is empty"));
  PowerAnalysis a = AnalyzePowers(BoolMatrix::PatternOf(m));
  if (!a.aperiodic())
    return absl::InvalidArgumentError(
        absl::StrCat("IFS matrix ", Quoted(name),
                     " is not aperiodic: the pattern of its non-empty entries cycles with period ",
                     a.period == 0 ? std::string("> 4096") : absl::StrCat(a.period),
                     " under powers, so its attractor matrix does not exist"));
  return std::move(a.limit);
}

absl::Status CheckAperiodic(const IfsMatrix& m, std::string_view name) {
  return AperiodicLimitPattern(m, name).status();
}

absl::Status CheckSelection(const BoolMatrix& limit, const std::vector<Component>& selection,
                            std::string_view name) {
  if (selection.empty())
    return absl::InvalidArgumentError(
        absl::StrCat("no component of IFS matrix ", Quoted(name), " is selected"));
  for (const Component& c : selection) {
    if (c.row >= limit.size() || c.col >= limit.size())
      return absl::InvalidArgumentError(absl::StrCat("component ", CellText(c.row, c.col),
                                                     " is outside IFS matrix ", Quoted(name),
                                                     " of size ", limit.size()));
    if (!limit.Get(c.row, c.col))
      return absl::InvalidArgumentError(
          absl::StrCat("component ", CellText(c.row, c.col), " of IFS matrix ", Quoted(name),
                       " is empty: no path of every long enough length leads from state ", c.row,
                       " to state ", c.col));
  }
  return absl::OkStatus();
}

}  // namespace nimbus
