#include "core/matrix/ifs_matrix.h"

#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <utility>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"

namespace nimbus {
namespace {

// A map without variations is affine even with a post: post o pre.
bool HasNoVariations(const PointMap& m) { return m.variations.empty(); }

Affine3 AffineOf(const PointMap& m) { return m.post ? *m.post * m.pre : m.pre; }

// absl here is built with its own string_view type, so std::string_view
// values go through std::string before reaching StrCat.
std::string Quoted(std::string_view s) {
  std::string out;
  out.reserve(s.size() + 2);
  out.push_back('\'');
  out.append(s);
  out.push_back('\'');
  return out;
}

std::string OpName(MatrixOp op) { return std::string(MatrixOpName(op)); }

std::string CellText(uint32_t i, uint32_t j) { return absl::StrCat("(", i, ", ", j, ")"); }

// Lists up to a dozen names for "unknown X" messages.
template <typename Range>
std::string NameList(const Range& names) {
  std::vector<std::string> shown;
  size_t total = 0;
  for (const auto& n : names) {
    if (shown.size() < 12) shown.emplace_back(n);
    ++total;
  }
  std::string out = absl::StrJoin(shown, ", ");
  if (total > shown.size()) absl::StrAppend(&out, ", ... (", total, " in all)");
  return total == 0 ? std::string("none") : out;
}

IfsMatrix::Entry SetUnion(const IfsMatrix::Entry& a, const IfsMatrix::Entry& b) {
  IfsMatrix::Entry out;
  out.reserve(a.size() + b.size());
  std::set_union(a.begin(), a.end(), b.begin(), b.end(), std::back_inserter(out));
  return out;
}

IfsMatrix::Entry SetIntersection(const IfsMatrix::Entry& a, const IfsMatrix::Entry& b) {
  IfsMatrix::Entry out;
  std::set_intersection(a.begin(), a.end(), b.begin(), b.end(), std::back_inserter(out));
  return out;
}

}  // namespace

// ---------------------------------------------------------------------------
// MapTable

MapTable::MapTable(std::vector<PointMap> base_maps) : maps_(std::move(base_maps)) {
  base_size_ = maps_.size();
  words_.reserve(maps_.size());
  for (uint32_t i = 0; i < maps_.size(); ++i) {
    words_.push_back({i});
    by_word_.emplace(words_.back(), i);
  }
  max_maps_ = std::max(max_maps_, maps_.size());
}

absl::StatusOr<uint32_t> MapTable::Find(std::string_view name) const {
  for (uint32_t i = 0; i < maps_.size(); ++i)
    if (maps_[i].name == name) return i;
  std::vector<std::string_view> names;
  for (const PointMap& m : maps_) names.push_back(m.name);
  return absl::NotFoundError(
      absl::StrCat("unknown map ", Quoted(name), "; defined maps: ", NameList(names)));
}

absl::StatusOr<uint32_t> MapTable::Append(PointMap map, std::vector<uint32_t> word) {
  if (maps_.size() >= max_maps_)
    return absl::ResourceExhaustedError(absl::StrCat("the map table is full (", max_maps_,
                                                     " maps) while adding ", Quoted(map.name)));
  const uint32_t index = static_cast<uint32_t>(maps_.size());
  maps_.push_back(std::move(map));
  by_word_.emplace(word, index);
  words_.push_back(std::move(word));
  return index;
}

absl::StatusOr<uint32_t> MapTable::Identity() {
  if (auto it = by_word_.find({}); it != by_word_.end()) return it->second;
  PointMap id;
  id.name = "identity";
  return Append(std::move(id), {});
}

absl::StatusOr<uint32_t> MapTable::Compose(uint32_t f, uint32_t g) {
  if (f >= maps_.size() || g >= maps_.size())
    return absl::OutOfRangeError(
        absl::StrCat("map index ", std::max(f, g), " is outside the table of ", maps_.size()));
  // Identity is neutral: no new entry, and the identity never hides in a word.
  if (IsIdentity(f)) return g;
  if (IsIdentity(g)) return f;
  std::vector<uint32_t> word = words_[f];
  word.insert(word.end(), words_[g].begin(), words_[g].end());
  if (auto it = by_word_.find(word); it != by_word_.end()) return it->second;

  const PointMap& outer = maps_[f];
  const PointMap& inner = maps_[g];
  if (!HasNoVariations(outer))
    return absl::InvalidArgumentError(absl::StrCat(
        "cannot compose ", Quoted(outer.name), " after ", Quoted(inner.name), ": ",
        Quoted(outer.name),
        " has nonlinear variations, and only an affine map can be composed after another map"));
  PointMap out;
  if (HasNoVariations(inner)) {
    out.pre = AffineOf(outer) * AffineOf(inner);
  } else {
    // The outer affine folds into the inner map's post; its variations, which
    // depend on their own pre-affine, stay untouched.
    out = inner;
    out.post = AffineOf(outer) * (inner.post ? *inner.post : Affine3::Identity());
  }
  out.name = absl::StrCat(outer.name, ".", inner.name);
  // The point's colour follows the last map applied, the outer one.
  out.color = outer.color;
  return Append(std::move(out), std::move(word));
}

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

// ---------------------------------------------------------------------------
// Expressions

std::string_view MatrixOpName(MatrixOp op) {
  switch (op) {
    case MatrixOp::kLeaf:
      return "leaf";
    case MatrixOp::kUnion:
      return "union";
    case MatrixOp::kIntersection:
      return "intersection";
    case MatrixOp::kComposition:
      return "compose";
    case MatrixOp::kTensorProduct:
      return "tensor_product";
    case MatrixOp::kTensorSum:
      return "tensor_sum";
    case MatrixOp::kBlockDiagonal:
      return "block_diag";
    case MatrixOp::kConcatenation:
      return "concat";
  }
  return "?";
}

namespace {

MatrixExprPtr MakeNode(MatrixOp op, std::vector<MatrixExprPtr> operands,
                       std::vector<MatrixLink> links = {}) {
  auto e = std::make_shared<MatrixExpr>();
  e->op = op;
  e->operands = std::move(operands);
  e->links = std::move(links);
  return e;
}

}  // namespace

MatrixExprPtr MatrixLeaf(std::string name, IfsMatrix matrix) {
  auto e = std::make_shared<MatrixExpr>();
  e->name = std::move(name);
  e->matrix = std::move(matrix);
  return e;
}
MatrixExprPtr MatrixUnion(std::vector<MatrixExprPtr> operands) {
  return MakeNode(MatrixOp::kUnion, std::move(operands));
}
MatrixExprPtr MatrixIntersection(std::vector<MatrixExprPtr> operands) {
  return MakeNode(MatrixOp::kIntersection, std::move(operands));
}
MatrixExprPtr MatrixComposition(std::vector<MatrixExprPtr> operands) {
  return MakeNode(MatrixOp::kComposition, std::move(operands));
}
MatrixExprPtr MatrixTensorProduct(MatrixExprPtr a, MatrixExprPtr b) {
  return MakeNode(MatrixOp::kTensorProduct, {std::move(a), std::move(b)});
}
MatrixExprPtr MatrixTensorSum(MatrixExprPtr a, MatrixExprPtr b) {
  return MakeNode(MatrixOp::kTensorSum, {std::move(a), std::move(b)});
}
MatrixExprPtr MatrixBlockDiagonal(std::vector<MatrixExprPtr> operands) {
  return MakeNode(MatrixOp::kBlockDiagonal, std::move(operands));
}
MatrixExprPtr MatrixConcatenation(MatrixExprPtr a, MatrixExprPtr b, std::vector<MatrixLink> links) {
  return MakeNode(MatrixOp::kConcatenation, {std::move(a), std::move(b)}, std::move(links));
}
MatrixExprPtr MatrixLabeled(std::string label, MatrixExprPtr expr) {
  auto e = std::make_shared<MatrixExpr>(*expr);
  e->name = std::move(label);
  return e;
}

std::string DescribeMatrixExpr(const MatrixExpr& expr) {
  if (!expr.name.empty()) return expr.name;
  if (expr.op == MatrixOp::kLeaf) return "<unnamed matrix>";
  std::vector<std::string> parts;
  for (const MatrixExprPtr& o : expr.operands)
    parts.push_back(o ? DescribeMatrixExpr(*o) : std::string("<null>"));
  for (const MatrixLink& l : expr.links) parts.push_back(absl::StrCat(l.from, "->", l.to));
  return absl::StrCat(OpName(expr.op), "(", absl::StrJoin(parts, ", "), ")");
}

namespace {

// Expands an expression bottom-up, enforcing the limits as results grow.
class Expander {
 public:
  Expander(MapTable& table, const ExpansionLimits& limits, std::vector<ExpansionStep>* report)
      : table_(table), limits_(limits), report_(report) {}

  absl::StatusOr<IfsMatrix> Eval(const MatrixExpr& e, int depth) {
    std::string what = DescribeMatrixExpr(e);
    if (what.size() > 160) what = what.substr(0, 157) + "...";
    absl::StatusOr<IfsMatrix> r = EvalNode(e, depth, what);
    if (r.ok() && report_) report_->push_back({what, depth, r->size(), r->MapReferences()});
    return r;
  }

 private:
  absl::StatusOr<IfsMatrix> EvalNode(const MatrixExpr& e, int depth, const std::string& what) {
    if (e.op == MatrixOp::kLeaf) {
      if (e.matrix.size() == 0)
        return absl::InvalidArgumentError(absl::StrCat("IFS matrix ", Quoted(what), " is empty"));
      if (absl::Status s = ValidateMatrix(e.matrix, table_.size(), what); !s.ok()) return s;
      if (absl::Status s = CheckSize(e.matrix.size(), what); !s.ok()) return s;
      if (absl::Status s = CheckRefs(e.matrix.MapReferences(), what); !s.ok()) return s;
      return e.matrix;
    }
    const bool binary = e.op == MatrixOp::kTensorProduct || e.op == MatrixOp::kTensorSum ||
                        e.op == MatrixOp::kConcatenation;
    if (binary ? e.operands.size() != 2 : e.operands.empty())
      return absl::InvalidArgumentError(absl::StrCat(
          Quoted(what), ": ", OpName(e.op), " takes ",
          binary ? "exactly two operands" : "at least one operand", ", got ", e.operands.size()));
    std::vector<IfsMatrix> args;
    for (const MatrixExprPtr& o : e.operands) {
      if (!o) return absl::InvalidArgumentError(absl::StrCat(Quoted(what), ": null operand"));
      absl::StatusOr<IfsMatrix> m = Eval(*o, depth + 1);
      if (!m.ok()) return m.status();
      args.push_back(*std::move(m));
    }
    switch (e.op) {
      case MatrixOp::kUnion:
      case MatrixOp::kIntersection:
      case MatrixOp::kComposition: {
        IfsMatrix acc = std::move(args[0]);
        for (size_t a = 1; a < args.size(); ++a) {
          if (args[a].size() != acc.size())
            return absl::InvalidArgumentError(
                absl::StrCat(Quoted(what), ": ", OpName(e.op), " needs equal sizes, got ",
                             acc.size(), " and ", args[a].size(), " (operand ", a + 1, ")"));
          absl::StatusOr<IfsMatrix> r = e.op == MatrixOp::kComposition
                                            ? Compose(acc, args[a], what)
                                            : Entrywise(acc, args[a], e.op, what);
          if (!r.ok()) return r.status();
          acc = *std::move(r);
        }
        return acc;
      }
      case MatrixOp::kTensorProduct:
      case MatrixOp::kTensorSum:
        return Tensor(args[0], args[1], e.op == MatrixOp::kTensorSum, what);
      case MatrixOp::kBlockDiagonal:
        return Blocks(args, {}, what);
      case MatrixOp::kConcatenation:
        return Blocks(args,
                      e.links.empty() ? std::vector<MatrixLink>{{args[0].size() - 1, 0}} : e.links,
                      what);
      case MatrixOp::kLeaf:
        break;
    }
    return absl::InternalError("unhandled matrix operation");
  }

  absl::Status CheckSize(uint64_t n, const std::string& what) const {
    if (n > limits_.max_size)
      return absl::ResourceExhaustedError(absl::StrCat("expanding ", Quoted(what), " gives a ", n,
                                                       " x ", n, " IFS matrix, above the limit of ",
                                                       limits_.max_size));
    return absl::OkStatus();
  }
  absl::Status CheckRefs(uint64_t refs, const std::string& what) const {
    if (refs > limits_.max_map_references)
      return absl::ResourceExhaustedError(
          absl::StrCat("expanding ", Quoted(what), " needs more than ", limits_.max_map_references,
                       " map references"));
    return absl::OkStatus();
  }

  absl::StatusOr<IfsMatrix> Entrywise(const IfsMatrix& a, const IfsMatrix& b, MatrixOp op,
                                      const std::string& what) {
    const uint32_t n = a.size();
    IfsMatrix out(n);
    uint64_t refs = 0;
    for (uint32_t i = 0; i < n; ++i)
      for (uint32_t j = 0; j < n; ++j) {
        IfsMatrix::Entry e = op == MatrixOp::kUnion ? SetUnion(a.at(i, j), b.at(i, j))
                                                    : SetIntersection(a.at(i, j), b.at(i, j));
        refs += e.size();
        if (absl::Status s = CheckRefs(refs, what); !s.ok()) return s;
        out.Set(i, j, std::move(e));
      }
    return out;
  }

  absl::StatusOr<IfsMatrix> Compose(const IfsMatrix& a, const IfsMatrix& b,
                                    const std::string& what) {
    const uint32_t n = a.size();
    IfsMatrix out(n);
    uint64_t refs = 0;
    table_.set_max_maps(std::max(limits_.max_table_maps, table_.size()));
    for (uint32_t i = 0; i < n; ++i)
      for (uint32_t j = 0; j < n; ++j) {
        IfsMatrix::Entry e;
        uint64_t pairs = 0;
        for (uint32_t k = 0; k < n; ++k) {
          if (a.empty(i, k) || b.empty(k, j)) continue;
          // Bound the work before composing: every pair may be a new map.
          pairs += uint64_t{a.at(i, k).size()} * b.at(k, j).size();
          if (pairs > limits_.max_map_references)
            return absl::ResourceExhaustedError(
                absl::StrCat("expanding ", Quoted(what), " composes more than ",
                             limits_.max_map_references, " map pairs in entry ", CellText(i, j)));
          for (uint32_t f : a.at(i, k))
            for (uint32_t g : b.at(k, j)) {
              absl::StatusOr<uint32_t> fg = table_.Compose(f, g);
              if (!fg.ok())
                return absl::Status(fg.status().code(),
                                    absl::StrCat("in ", Quoted(what), " entry ", CellText(i, j),
                                                 ": ", fg.status().message()));
              e.push_back(*fg);
            }
        }
        std::sort(e.begin(), e.end());
        e.erase(std::unique(e.begin(), e.end()), e.end());
        refs += e.size();
        if (absl::Status s = CheckRefs(refs, what); !s.ok()) return s;
        out.Set(i, j, std::move(e));
      }
    return out;
  }

  // Product: H_ij u K_kl everywhere. Sum (shuffle): the Kronecker sum
  // H (x) I u I (x) K with composition as the product, so the identity
  // entries vanish (id o f = f) and only [k==l] H_ij u [i==j] K_kl remains.
  absl::StatusOr<IfsMatrix> Tensor(const IfsMatrix& a, const IfsMatrix& b, bool sum,
                                   const std::string& what) {
    const uint32_t n = a.size(), m = b.size();
    if (absl::Status s = CheckSize(uint64_t{n} * m, what); !s.ok()) return s;
    IfsMatrix out(n * m);
    static const IfsMatrix::Entry kNone;
    uint64_t refs = 0;
    for (uint32_t i = 0; i < n; ++i)
      for (uint32_t j = 0; j < n; ++j)
        for (uint32_t k = 0; k < m; ++k)
          for (uint32_t l = 0; l < m; ++l) {
            const IfsMatrix::Entry& x = (!sum || k == l) ? a.at(i, j) : kNone;
            const IfsMatrix::Entry& y = (!sum || i == j) ? b.at(k, l) : kNone;
            IfsMatrix::Entry e = SetUnion(x, y);
            refs += e.size();
            if (absl::Status s = CheckRefs(refs, what); !s.ok()) return s;
            out.Set(i * m + k, j * m + l, std::move(e));
          }
    return out;
  }

  // Block diagonal of all operands; links (two operands) add the identity
  // from a state of the first block to a state of the second.
  absl::StatusOr<IfsMatrix> Blocks(const std::vector<IfsMatrix>& args,
                                   const std::vector<MatrixLink>& links, const std::string& what) {
    uint64_t total = 0, refs = links.size();
    for (const IfsMatrix& a : args) total += a.size(), refs += a.MapReferences();
    if (absl::Status s = CheckSize(total, what); !s.ok()) return s;
    if (absl::Status s = CheckRefs(refs, what); !s.ok()) return s;
    IfsMatrix out(static_cast<uint32_t>(total));
    uint32_t offset = 0;
    for (const IfsMatrix& a : args) {
      for (uint32_t i = 0; i < a.size(); ++i)
        for (uint32_t j = 0; j < a.size(); ++j) out.Set(offset + i, offset + j, a.at(i, j));
      offset += a.size();
    }
    if (!links.empty()) {
      table_.set_max_maps(std::max(limits_.max_table_maps, table_.size()));
      absl::StatusOr<uint32_t> id = table_.Identity();
      if (!id.ok()) return id.status();
      const uint32_t n = args[0].size();
      for (const MatrixLink& l : links) {
        if (l.from >= n || l.to >= args[1].size())
          return absl::InvalidArgumentError(absl::StrCat(Quoted(what), ": link ", l.from, "->",
                                                         l.to, " is outside the operands' sizes ",
                                                         n, " and ", args[1].size()));
        out.Insert(l.from, n + l.to, *id);
      }
    }
    return out;
  }

  MapTable& table_;
  const ExpansionLimits& limits_;
  std::vector<ExpansionStep>* report_;
};

}  // namespace

absl::StatusOr<IfsMatrix> EvaluateMatrixExpr(const MatrixExpr& expr, MapTable& table,
                                             const ExpansionLimits& limits,
                                             std::vector<ExpansionStep>* report) {
  const size_t saved = table.max_maps();
  Expander x(table, limits, report);
  absl::StatusOr<IfsMatrix> r = x.Eval(expr, 0);
  table.set_max_maps(std::max(saved, table.size()));
  return r;
}

absl::Status MatrixCatalog::Add(std::string name, IfsMatrix matrix) {
  if (name.empty()) return absl::InvalidArgumentError("an IFS matrix needs a name");
  if (leaves_.count(name))
    return absl::AlreadyExistsError(absl::StrCat("IFS matrix ", Quoted(name), " is defined twice"));
  MatrixExprPtr leaf = MatrixLeaf(name, std::move(matrix));
  leaves_.emplace(std::move(name), std::move(leaf));
  return absl::OkStatus();
}

absl::StatusOr<MatrixExprPtr> MatrixCatalog::Find(std::string_view name) const {
  if (auto it = leaves_.find(name); it != leaves_.end()) return it->second;
  std::vector<std::string_view> names;
  for (const auto& [n, e] : leaves_) names.push_back(n);
  return absl::NotFoundError(
      absl::StrCat("unknown IFS matrix ", Quoted(name), "; defined matrices: ", NameList(names)));
}

// ---------------------------------------------------------------------------
// Deterministic rendering

absl::StatusOr<std::vector<Vec3>> RenderComponentDeterministic(
    const std::vector<PointMap>& maps, const IfsMatrix& m, Component c, int depth,
    const DeterministicRenderOptions& options) {
  const uint32_t n = m.size();
  if (c.row >= n || c.col >= n)
    return absl::InvalidArgumentError(
        absl::StrCat("component ", CellText(c.row, c.col), " is outside a matrix of size ", n));
  constexpr int kMaxDepth = 1 << 16;
  if (depth < 0 || depth > kMaxDepth)
    return absl::InvalidArgumentError(absl::StrCat("depth must be in [0, ", kMaxDepth, "]"));
  if (absl::Status s = ValidateMatrix(m, maps.size(), "rendered matrix"); !s.ok()) return s;

  // reach[t]: states row i reaches in exactly t steps.
  std::vector<std::vector<char>> reach(depth + 1, std::vector<char>(n, 0));
  reach[0][c.row] = 1;
  for (int t = 1; t <= depth; ++t)
    for (uint32_t r = 0; r < n; ++r)
      if (reach[t - 1][r])
        for (uint32_t s = 0; s < n; ++s)
          if (!m.empty(r, s)) reach[t][s] = 1;

  // Word counts first, so an oversized render is refused before any work.
  std::vector<double> count(n, 0.0), next(n);
  count[c.col] = reach[depth][c.col] ? 1.0 : 0.0;
  for (int t = 1; t <= depth; ++t) {
    std::fill(next.begin(), next.end(), 0.0);
    for (uint32_t r = 0; r < n; ++r) {
      if (!reach[depth - t][r]) continue;
      for (uint32_t s = 0; s < n; ++s) next[r] += double(m.at(r, s).size()) * count[s];
    }
    std::swap(count, next);
  }
  if (count[c.row] > double(options.max_points))
    return absl::ResourceExhaustedError(
        absl::StrCat("rendering component ", CellText(c.row, c.col), " to depth ", depth, " needs ",
                     count[c.row], " points, above the limit of ", options.max_points));

  // pts[s] = (H^t)_{s j}(start) for the rows still useful after t steps.
  Rng rng(options.seed, 0);
  std::vector<std::vector<Vec3>> pts(n), fresh(n);
  if (reach[depth][c.col]) pts[c.col].push_back(options.start);
  for (int t = 1; t <= depth; ++t) {
    for (auto& v : fresh) v.clear();
    for (uint32_t r = 0; r < n; ++r) {
      if (!reach[depth - t][r]) continue;
      for (uint32_t s = 0; s < n; ++s)
        for (uint32_t f : m.at(r, s))
          for (const Vec3& p : pts[s]) fresh[r].push_back(maps[f].Apply(p, rng));
    }
    std::swap(pts, fresh);
  }
  return std::move(pts[c.row]);
}

// ---------------------------------------------------------------------------
// Chain construction

namespace {

// Tarjan's strongly connected components, iterative. Returns the class id
// of every vertex.
std::vector<uint32_t> StronglyConnected(const BoolMatrix& g) {
  const uint32_t n = g.size();
  constexpr uint32_t kUnset = std::numeric_limits<uint32_t>::max();
  std::vector<uint32_t> index(n, kUnset), low(n, 0), comp(n, kUnset), stack;
  std::vector<char> on_stack(n, 0);
  struct Frame {
    uint32_t v, next;
  };
  std::vector<Frame> calls;
  uint32_t counter = 0, classes = 0;
  for (uint32_t root = 0; root < n; ++root) {
    if (index[root] != kUnset) continue;
    auto visit = [&](uint32_t v) {
      index[v] = low[v] = counter++;
      stack.push_back(v);
      on_stack[v] = 1;
      calls.push_back({v, 0});
    };
    visit(root);
    while (!calls.empty()) {
      const uint32_t v = calls.back().v;
      if (calls.back().next < n) {
        const uint32_t w = calls.back().next++;
        if (!g.Get(v, w)) continue;
        if (index[w] == kUnset) {
          visit(w);
        } else if (on_stack[w]) {
          low[v] = std::min(low[v], index[w]);
        }
        continue;
      }
      if (low[v] == index[v]) {
        uint32_t w;
        do {
          w = stack.back();
          stack.pop_back();
          on_stack[w] = 0;
          comp[w] = classes;
        } while (w != v);
        ++classes;
      }
      calls.pop_back();
      if (!calls.empty()) low[calls.back().v] = std::min(low[calls.back().v], low[v]);
    }
  }
  return comp;
}

}  // namespace

absl::StatusOr<ComponentChain> BuildComponentChain(const std::vector<PointMap>& maps,
                                                   const IfsMatrix& m,
                                                   const std::vector<Component>& selection,
                                                   std::string_view name,
                                                   const ComponentChainOptions& options) {
  if (absl::Status s = ValidateMatrix(m, maps.size(), name); !s.ok()) return s;
  absl::StatusOr<BoolMatrix> limit = AperiodicLimitPattern(m, name);
  if (!limit.ok()) return limit.status();
  if (absl::Status s = CheckSelection(*limit, selection, name); !s.ok()) return s;
  const uint32_t n = m.size();
  const BoolMatrix r = BoolMatrix::PatternOf(m);

  // Per-map weights.
  std::vector<double> weight(maps.size(), 0.0);
  if (!options.map_weights.empty()) {
    if (options.map_weights.size() != maps.size())
      return absl::InvalidArgumentError(absl::StrCat("IFS matrix ", Quoted(name), ": ",
                                                     options.map_weights.size(),
                                                     " map weights for ", maps.size(), " maps"));
    for (size_t f = 0; f < maps.size(); ++f) {
      const double w = options.map_weights[f];
      if (!(w > 0) || !std::isfinite(w))
        return absl::InvalidArgumentError(absl::StrCat("IFS matrix ", Quoted(name),
                                                       ": the weight of map ", Quoted(maps[f].name),
                                                       " must be positive and finite"));
      weight[f] = w;
    }
  } else {
    double largest = 0;
    for (uint32_t i = 0; i < n; ++i)
      for (uint32_t j = 0; j < n; ++j)
        for (uint32_t f : m.at(i, j)) {
          weight[f] = std::fabs(maps[f].pre.Determinant());
          largest = std::max(largest, weight[f]);
        }
    if (!(largest > 0)) largest = 1;
    for (double& w : weight) w = std::max(w, options.probability_floor * largest);
    for (double& w : weight)
      if (!(w > 0)) w = 1;  // a zero floor on an all-degenerate matrix: uniform
  }

  const std::vector<uint32_t> scc = StronglyConnected(r);

  // Selected columns in order of first appearance; label of every selected
  // (row, col) is its first index in `selection`.
  std::vector<uint32_t> columns;
  std::map<std::pair<uint32_t, uint32_t>, int32_t> label;
  for (size_t k = 0; k < selection.size(); ++k) {
    const Component c = selection[k];
    if (std::find(columns.begin(), columns.end(), c.col) == columns.end()) columns.push_back(c.col);
    label.emplace(std::make_pair(c.row, c.col), static_cast<int32_t>(k));
  }

  ComponentChain out;
  MarkovChain& chain = out.chain;
  struct Entry {
    uint32_t state;  // level-0 warm-up copy of the entry state (or the hub)
    uint32_t map;    // map used on the step into the warm-up
  };
  std::vector<Entry> entries;
  // Live states that restart, and how (filled after all blocks exist).
  std::vector<std::pair<uint32_t, bool>> restarting;  // (chain state, must)
  uint32_t longest_warmup = 1;

  using Kind = ComponentChain::Kind;
  auto add_state = [&](Kind kind, uint32_t row, uint32_t col, uint32_t level) {
    out.states.push_back({kind, row, col, level});
    chain.states.emplace_back();
    chain.states.back().plotted = false;
    chain.states.back().label = -1;
    return static_cast<uint32_t>(chain.states.size() - 1);
  };
  auto too_many = [&](size_t more) {
    return chain.states.size() + more > options.max_states
               ? absl::ResourceExhaustedError(absl::StrCat("the chain for IFS matrix ",
                                                           Quoted(name), " needs more than ",
                                                           options.max_states, " states"))
               : absl::OkStatus();
  };
  auto add_transition = [&](uint32_t state, uint32_t map, uint32_t next) {
    chain.states[state].transitions.push_back({map, next});
    chain.states[state].probabilities.push_back(weight[map]);
  };

  for (uint32_t j : columns) {
    // Live set: rows with a non-empty component in column j that a selected
    // row of this column reaches through such rows.
    std::vector<char> live(n, 0);
    std::vector<uint32_t> queue;
    for (const Component& c : selection)
      if (c.col == j && !live[c.row]) live[c.row] = 1, queue.push_back(c.row);
    for (size_t q = 0; q < queue.size(); ++q)
      for (uint32_t s = 0; s < n; ++s)
        if (r.Get(queue[q], s) && limit->Get(s, j) && !live[s]) live[s] = 1, queue.push_back(s);

    if (absl::Status s = too_many(queue.size()); !s.ok()) return s;
    std::vector<uint32_t> index(n, 0);
    for (uint32_t s = 0; s < n; ++s) {
      if (!live[s]) continue;
      index[s] = add_state(Kind::kLive, s, j, 0);
      if (auto it = label.find({s, j}); it != label.end()) {
        chain.states[index[s]].plotted = true;
        chain.states[index[s]].label = it->second;
      }
    }
    // Predecessor edges inside the block.
    for (uint32_t s = 0; s < n; ++s) {
      if (!live[s]) continue;
      for (uint32_t p = 0; p < n; ++p)
        if (live[p])
          for (uint32_t f : m.at(p, s)) add_transition(index[s], f, index[p]);
    }
    // Sink classes of the block: no edge to another live class.
    std::vector<char> is_sink(n, 1);  // by class id
    for (uint32_t s = 0; s < n; ++s)
      if (live[s])
        for (uint32_t t = 0; t < n; ++t)
          if (live[t] && r.Get(s, t) && scc[t] != scc[s]) is_sink[scc[s]] = 0;

    std::vector<char> class_done(n, 0);
    for (uint32_t s = 0; s < n; ++s) {
      if (!live[s] || !is_sink[scc[s]] || class_done[scc[s]]) continue;
      const uint32_t cls = scc[s];
      class_done[cls] = 1;
      std::vector<uint32_t> members;
      for (uint32_t t = 0; t < n; ++t)
        if (live[t] && scc[t] == cls) members.push_back(t);
      // Warm-up length from the class's internal maps.
      uint32_t steps = options.warmup_steps;
      bool has_internal = false;
      uint32_t entry_map = 0;
      double c_max = 0;
      bool unknown = false;
      for (uint32_t a : members)
        for (uint32_t b : members)
          for (uint32_t f : m.at(a, b)) {
            if (!has_internal) entry_map = f;  // any bounded map will do
            has_internal = true;
            if (!HasNoVariations(maps[f])) unknown = true;
            c_max = std::max(c_max, AffineOf(maps[f]).ContractionFactor());
          }
      if (!has_internal)
        return absl::InternalError(absl::StrCat("IFS matrix ", Quoted(name),
                                                ": sink class of state ", s, " has no cycle"));
      if (steps == 0) {
        if (unknown || !(c_max < 1)) {
          steps = options.fallback_warmup_steps;
        } else if (c_max <= 0) {
          steps = 1;
        } else {
          const double l = std::ceil(std::log(options.warmup_tolerance) / std::log(c_max));
          steps = static_cast<uint32_t>(std::clamp(l, 1.0, 4096.0));
        }
        steps = std::max<uint32_t>(steps, 1);
      }
      longest_warmup = std::max(longest_warmup, steps);
      // Level copies; the last level feeds the live states.
      if (absl::Status s = too_many(size_t{steps} * members.size()); !s.ok()) return s;
      // Copies are laid out level by level: copy (l, a) is first + l*size + pos(a).
      std::vector<uint32_t> pos(n, 0);
      for (uint32_t k = 0; k < members.size(); ++k) pos[members[k]] = k;
      const uint32_t first = static_cast<uint32_t>(chain.states.size());
      const uint32_t width = static_cast<uint32_t>(members.size());
      for (uint32_t l = 0; l < steps; ++l)
        for (uint32_t a : members) add_state(Kind::kWarmup, a, j, l);
      for (uint32_t l = 0; l < steps; ++l)
        for (uint32_t a : members)
          for (uint32_t p : members)
            for (uint32_t f : m.at(p, a))
              add_transition(first + l * width + pos[a], f,
                             l + 1 < steps ? first + (l + 1) * width + pos[p] : index[p]);
      entries.push_back({first + pos[members[0]], entry_map});
    }
    // Which live states restart: outside sink classes, or stuck.
    for (uint32_t s = 0; s < n; ++s)
      if (live[s])
        restarting.push_back(
            {index[s], !is_sink[scc[s]] || chain.states[index[s]].transitions.empty()});
  }
  if (entries.empty()) return absl::InternalError("no sink class to start the chain from");

  const bool many_blocks = columns.size() > 1;
  double rho = options.restart_probability;
  if (!(rho > 0)) rho = 1.0 / (2.0 * longest_warmup);
  rho = std::clamp(rho, 1e-9, 1.0);
  // Where a restart goes: straight into the only warm-up, or to a hub that
  // picks one uniformly.
  Entry target = entries[0];
  if (entries.size() > 1) {
    if (absl::Status s = too_many(1); !s.ok()) return s;
    const uint32_t hub = add_state(Kind::kRestart, 0, 0, 0);
    for (const Entry& e : entries) add_transition(hub, e.map, e.state);
    chain.states[hub].probabilities.assign(entries.size(), 1.0);
    target = {hub, entries[0].map};
  }
  for (auto [state, needs] : restarting) {
    ChainState& st = chain.states[state];
    if (!needs && !many_blocks) continue;
    const double p_restart = st.transitions.empty() ? 1.0 : rho;
    // Normalise the regular part to 1 - p_restart, then add the restart.
    double total = 0;
    for (double w : st.probabilities) total += w;
    for (double& w : st.probabilities) w = w / total * (1.0 - p_restart);
    st.transitions.push_back({target.map, target.state});
    st.probabilities.push_back(p_restart);
  }
  // Normalise every state (restarting ones are already, up to rounding).
  for (ChainState& st : chain.states) {
    double total = 0;
    for (double w : st.probabilities) total += w;
    for (double& w : st.probabilities) w /= total;
  }
  // Several blocks start at the hub, so the first block is not favoured.
  chain.start_state = target.state;
  return out;
}

// ---------------------------------------------------------------------------
// Reference chaos game

absl::StatusOr<ReferenceChaosResult> RunChainReference(const std::vector<PointMap>& maps,
                                                       const MarkovChain& chain,
                                                       const GridFrame& frame, uint64_t iterations,
                                                       uint32_t warmup, uint64_t seed,
                                                       Interrupter* interrupter) {
  const Int3 res = frame.resolution;
  if (res.x <= 0 || res.y <= 0 || res.z <= 0)
    return absl::InvalidArgumentError("grid resolution must be positive on every axis");
  const Vec3 size = frame.bounds.Size();
  if (!(size.x > 0 && size.y > 0 && size.z > 0))
    return absl::InvalidArgumentError("grid bounds must have max > min on every axis");
  if (chain.states.empty() || chain.start_state >= chain.states.size())
    return absl::InvalidArgumentError("the chain has no states or a missing start state");
  int32_t labels = 0;
  std::vector<AliasTable> tables;
  for (size_t s = 0; s < chain.states.size(); ++s) {
    const ChainState& st = chain.states[s];
    if (st.transitions.empty() || st.transitions.size() != st.probabilities.size())
      return absl::InvalidArgumentError(
          absl::StrCat("chain state ", s, " needs transitions with one probability each"));
    double total = 0;
    for (size_t t = 0; t < st.transitions.size(); ++t) {
      if (st.transitions[t].map >= maps.size() ||
          st.transitions[t].next_state >= chain.states.size())
        return absl::InvalidArgumentError(
            absl::StrCat("chain state ", s, " has a transition to a missing map or state"));
      if (!(st.probabilities[t] >= 0))
        return absl::InvalidArgumentError(
            absl::StrCat("chain state ", s, " has a negative probability"));
      total += st.probabilities[t];
    }
    if (std::fabs(total - 1.0) > 1e-9)
      return absl::InvalidArgumentError(
          absl::StrCat("chain state ", s, " probabilities sum to ", total, ", not 1"));
    tables.emplace_back(st.probabilities);
    if (st.plotted) labels = std::max(labels, st.label + 1);
  }

  ReferenceChaosResult out(res);
  for (int32_t l = 0; l < labels; ++l) out.labels.emplace_back(res);
  Interrupter& intr = OrNull(interrupter);
  intr.Start("reference chaos game");
  Rng rng(seed, 0);
  const Bounds& b = frame.bounds;
  const Vec3 vs = frame.VoxelSize();
  Vec3 p;
  uint32_t state = 0;
  auto step = [&] {
    const ChainState& st = chain.states[state];
    const ChainTransition& t = st.transitions[tables[state].Sample(rng.Next())];
    p = maps[t.map].Apply(p, rng);
    state = t.next_state;
    return IsFinite(p);
  };
  auto restart = [&] {
    p = {rng.Uniform(b.min.x, b.max.x), rng.Uniform(b.min.y, b.max.y),
         rng.Uniform(b.min.z, b.max.z)};
    state = chain.start_state;
    for (uint32_t i = 0; i < warmup; ++i)
      if (!step()) {
        p = {rng.Uniform(b.min.x, b.max.x), rng.Uniform(b.min.y, b.max.y),
             rng.Uniform(b.min.z, b.max.z)};
        ++out.reseeded;
      }
  };
  restart();
  for (uint64_t it = 0; it < iterations; ++it) {
    if ((it & 0xffff) == 0 && intr.WasInterrupted(it, iterations)) {
      intr.End();
      return absl::CancelledError("reference chaos game interrupted");
    }
    if (!step()) {
      ++out.reseeded;
      restart();
      continue;
    }
    const ChainState& st = chain.states[state];
    if (!st.plotted) continue;
    const double fx = (p.x - b.min.x) / vs.x, fy = (p.y - b.min.y) / vs.y,
                 fz = (p.z - b.min.z) / vs.z;
    if (!(fx >= 0 && fx < res.x && fy >= 0 && fy < res.y && fz >= 0 && fz < res.z)) {
      ++out.outside;
      continue;
    }
    const int x = int(fx), y = int(fy), z = int(fz);
    out.counts.Add(x, y, z);
    if (st.label >= 0) out.labels[st.label].Add(x, y, z);
    ++out.plotted;
  }
  intr.End();
  return out;
}

// ---------------------------------------------------------------------------
// Worked example

IfsMatrixExample TreeMatrixExample() {
  const Affine3 half = Affine3::Scale({0.5, 0.5, 0.5});
  const Affine3 up = Affine3::Translate({0, 1, 0});
  IfsMatrixExample ex;
  ex.maps.resize(4);
  ex.maps[0].name = "T1";
  ex.maps[0].pre = half;
  ex.maps[1].name = "T2";
  ex.maps[1].pre = Affine3::Translate({0, 0.5, 0}) * half;
  ex.maps[2].name = "T3";
  ex.maps[2].pre = up * Affine3::Rotate({1, 0, 0}, 45) * half;
  ex.maps[3].name = "T4";
  ex.maps[3].pre = up * Affine3::Rotate({1, 0, 0}, -45) * half;
  for (int i = 0; i < 4; ++i) ex.maps[i].color = i / 3.0;
  ex.matrix = *IfsMatrix::FromRows({{{2, 3}, {0, 1}}, {{}, {0, 1}}});
  return ex;
}

}  // namespace nimbus
