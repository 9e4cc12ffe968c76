#include "core/sets/feature_transform.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstring>
#include <limits>

#include "absl/strings/str_cat.h"
#include "core/base/status_macros.h"

namespace nimbus {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

// Per-thread buffers for one line of a pass.
struct LineScratch {
  std::vector<int> pos;        // site positions along the line
  std::vector<double> c;       // g_i + w pos_i^2 (g: the cost from earlier axes)
  std::vector<PackedVoxel> f;  // site features
  // The envelope as a stack of its sites' values (not indices into the
  // site arrays): the pop test then reads adjacent entries, not scattered
  // ones through a level of indirection.
  std::vector<double> hc;
  std::vector<double> hp;  // integer positions, held as doubles: no conversions in the loops
  std::vector<PackedVoxel> hf;
  void Reserve(int n) {
    pos.resize(n);
    c.resize(n);
    f.resize(n);
    hc.resize(n);
    hp.resize(n);
    hf.resize(n);
  }
};

// Copies one tile row: a fixed-size copy for whole blocks, so the compiler
// emits two vector moves instead of a library call.
template <int kBlock>
inline void CopyRow(const PackedVoxel* from, int n, PackedVoxel* to) {
  if (n == kBlock)
    std::memcpy(to, from, sizeof(PackedVoxel) * kBlock);
  else
    std::copy_n(from, n, to);
}

// Lower envelope of the parabolas g_i + w (q - pos_i)^2 for m sites in
// increasing position, then the winning feature for every position q in
// [q0 + lo, q0 + hi), written to out[(q - q0) * stride]. Positions are lattice
// coordinates, not box-relative ones, so a line computed inside any box
// does the same floating-point operations and breaks ties the same way.
// Works on c_i = g_i + w pos_i^2, which the caller stores (w pos^2 comes
// from a table per pass: the same double for every line), and
// cross-multiplied intersection tests (no divisions: they dominated the
// pass). Equal curvatures mean the rightmost site always wins far enough
// right, so each new site is pushed after popping the ones it hides.
void EnvelopeLine(LineScratch& s, int m, double w, int q0, int lo, int hi, PackedVoxel* out,
                  size_t stride) {
  const double* c = s.c.data();
  const int* p = s.pos.data();
  const PackedVoxel* f = s.f.data();
  double* hc = s.hc.data();
  double* hp = s.hp.data();
  PackedVoxel* hf = s.hf.data();
  int k = 0;
  hc[0] = c[0];
  hp[0] = p[0];
  hf[0] = f[0];
  for (int i = 1; i < m; ++i) {
    const double ci = c[i];
    const double pi = p[i];  // differences of these are exact, as the ints' were
    // Pop the top while the new parabola overtakes it no later than it
    // overtakes the one below.
    while (k > 0) {
      if ((hc[k] - hc[k - 1]) * (pi - hp[k]) < (ci - hc[k]) * (hp[k] - hp[k - 1])) break;
      --k;
    }
    ++k;
    hc[k] = ci;
    hp[k] = pi;
    hf[k] = f[i];
  }
  // Only positions [q0 + lo, q0 + hi) are written. Starting the walk at
  // q0 + lo instead of q0 changes nothing: whether the next parabola is
  // lower only ever turns from false to true as q grows (the rounded
  // products are monotone in q too), so the walk stops where it would have.
  // The current pair's differences stay in registers; once the last
  // parabola is reached it wins every remaining position.
  // q = q0 + i is counted in a double (exact for integers), so the test
  // rounds exactly as 2.0 * w * (q0 + i) * dp did.
  const double w2 = 2.0 * w;
  int h = 0, i = lo;
  double q = double(q0 + lo);
  while (h < k && i < hi) {
    const double dc = hc[h + 1] - hc[h], dp = hp[h + 1] - hp[h];
    const PackedVoxel fu = hf[h];
    // Positions where the next parabola is not strictly lower stay with u.
    for (; i < hi && !(dc < w2 * q * dp); ++i, q += 1.0) out[size_t(i) * stride] = fu;
    if (i < hi) ++h;
  }
  const PackedVoxel last = hf[h];
  for (; i < hi; ++i) out[size_t(i) * stride] = last;
}

int Square(int v) { return v * v; }

// First x in [from, x1] whose bit differs from `flip` (0: the first member,
// all ones: the first non-member), or x1 + 1 when there is none.
inline int NextBit(const uint64_t* row, int from, int x1, uint64_t flip) {
  int w = from >> 6;
  uint64_t bits = (row[w] ^ flip) & (~uint64_t{0} << (from & 63));
  while (!bits) {
    if (++w > x1 >> 6) return x1 + 1;
    bits = row[w] ^ flip;
  }
  return std::min((w << 6) + std::countr_zero(bits), x1 + 1);
}

// Box-relative ranges of the last two passes that queries need: rows
// [ylo, yhi) of each x column of each slice (pass 2, indexed z * size.x +
// x) and slices [zlo, zhi) of each (x, y) column (pass 3, indexed
// y * size.x + x). An empty range (lo >= hi) means the column is not
// needed. `reach_y` (per pass-2 line) and `reach_z` (per pass-3 column)
// bound how far, in voxels, a site can lie from the positions the line
// writes and still matter (see SiteReach). Pass 1 computes rows
// [row_lo, row_hi) of each slice only: the sites and rows pass 2 reads.
struct NeedRanges {
  std::vector<int> ylo, yhi, zlo, zhi, reach_y, reach_z, row_lo, row_hi;
};

// Each slice's rows that its pass-2 lines read: their ranges widened by
// their reaches (none when no line of the slice is needed).
void SliceRows(Int3 b, NeedRanges& need) {
  need.row_lo.assign(size_t(b.z), 0);
  need.row_hi.assign(size_t(b.z), 0);
  for (int zi = 0; zi < b.z; ++zi) {
    int lo = b.y, hi = 0;
    for (size_t i = size_t(zi) * b.x; i < size_t(zi + 1) * b.x; ++i) {
      if (need.ylo[i] >= need.yhi[i]) continue;
      lo = std::min(lo, need.ylo[i] - need.reach_y[i]);
      hi = std::max(hi, need.yhi[i] + need.reach_y[i]);
    }
    need.row_lo[size_t(zi)] = std::max(0, lo);
    need.row_hi[size_t(zi)] = std::min(b.y, hi);
  }
}

void AllRanges(Int3 b, NeedRanges& need) {
  need.ylo.assign(size_t(b.x) * b.z, 0);
  need.yhi.assign(size_t(b.x) * b.z, b.y);
  need.reach_y.assign(size_t(b.x) * b.z, b.y);
  need.zlo.assign(size_t(b.x) * b.y, 0);
  need.zhi.assign(size_t(b.x) * b.y, b.z);
  need.reach_z.assign(size_t(b.x) * b.y, b.z);
  SliceRows(b, need);
}

// Integer weights k with w_a = k_a 2^e for every axis, when they exist and
// are small (k_a <= 2^16). The double arithmetic of the passes (products
// of w, positions and their differences, below 2^53 2^e) is then exact,
// which is what makes site pruning safe: see SiteReach.
std::optional<Int3> ExactWeights(double wx, double wy, double wz) {
  const double w[3] = {wx, wy, wz};
  int64_t odd[3];
  int low[3];  // w_a = odd_a 2^low_a
  for (int a = 0; a < 3; ++a) {
    if (!(w[a] >= 0x1p-900 && w[a] <= 0x1p900)) return std::nullopt;
    int e;
    const double m = std::frexp(w[a], &e);  // w = m 2^e, m in [0.5, 1)
    int64_t mant = int64_t(std::ldexp(m, 53));
    low[a] = e - 53;
    while (!(mant & 1)) {
      mant >>= 1;
      ++low[a];
    }
    odd[a] = mant;
  }
  const int e = std::min({low[0], low[1], low[2]});
  int k[3];
  for (int a = 0; a < 3; ++a) {
    if (low[a] - e > 16 || odd[a] > (int64_t{1} << 16)) return std::nullopt;
    const int64_t v = odd[a] << (low[a] - e);
    if (v > (int64_t{1} << 16)) return std::nullopt;
    k[a] = int(v);
  }
  return Int3{k[0], k[1], k[2]};
}

// Bits of the box's rows, x from word w0, one row of nw words per (y, z).
struct BoxBits {
  Int3 size;
  int w0 = 0, nw = 0;
  std::vector<uint64_t, BigBufferAllocator<uint64_t>> bits;  // CopyBits writes them all
  uint64_t* Row(int yi, int zi) { return bits.data() + (size_t(zi) * size.y + yi) * nw; }
};

BoxBits CopyBits(const VoxelSet& set, const VoxelBox& box) {
  BoxBits b{box.Size(), box.min.x >> 6, (box.max.x >> 6) - (box.min.x >> 6) + 1, {}};
  b.bits.resize(size_t(b.nw) * b.size.y * b.size.z);
  tbb::parallel_for(tbb::blocked_range<int>(0, b.size.z, 8), [&](const tbb::blocked_range<int>& r) {
    for (int zi = r.begin(); zi < r.end(); ++zi)
      for (int yi = 0; yi < b.size.y; ++yi)
        std::copy_n(set.Row(box.min.y + yi, box.min.z + zi) + b.w0, b.nw, b.Row(yi, zi));
  });
  return b;
}

// Rows [y0, y1] of slices [z0, z1] of a BoxBits, words [w0, w1] of each
// (inclusive, box-relative); empty when y0 > y1.
struct BitRegion {
  int y0 = 0, y1 = -1, z0 = 0, z1 = -1, w0 = 0, w1 = -1;
  bool Empty() const { return y0 > y1; }
  void Add(int y, int z, int w) {
    if (Empty()) {
      *this = {y, y, z, z, w, w};
      return;
    }
    y0 = std::min(y0, y);
    y1 = std::max(y1, y);
    z0 = std::min(z0, z);
    z1 = std::max(z1, z);
    w0 = std::min(w0, w);
    w1 = std::max(w1, w);
  }
  // Grown by e rows and slices and by `words` words, clipped to the box.
  BitRegion Grown(int e, int words, const BoxBits& d) const {
    return {std::max(0, y0 - e),         std::min(d.size.y - 1, y1 + e),
            std::max(0, z0 - e),         std::min(d.size.z - 1, z1 + e),
            std::max(0, w0 - words),     std::min(d.nw - 1, w1 + words)};
  }
};

// A row's words beyond the box edge (rows are at most 17 words wide).
constexpr uint64_t kZeroWords[32] = {};
static_assert(VoxelSet::kMaxResolution / 64 + 1 <= 32);

// A few words: an inline loop, not a library call per row.
inline void CopyWords(const uint64_t* from, int n, uint64_t* to) {
  for (int i = 0; i < n; ++i) to[i] = from[i];
}

// The three steps of DilateOnce over part of the region (e grown by one
// row, slice and word is g). Along x, rows of slices [z0, z1) of g, each
// word from its old neighbours (the carry keeps the one overwritten).
void DilateAlongX(BoxBits& d, const BitRegion& g, int z0, int z1) {
  for (int zi = z0; zi < z1; ++zi)
    for (int yi = g.y0; yi <= g.y1; ++yi) {
      uint64_t* r = d.Row(yi, zi);
      uint64_t carry_lo = g.w0 > 0 ? r[g.w0 - 1] >> 63 : 0;
      for (int w = g.w0; w <= g.w1; ++w) {
        const uint64_t v = r[w], next = w + 1 < d.nw ? r[w + 1] : 0;
        r[w] = v | (v << 1) | carry_lo | (v >> 1) | (next << 63);
        carry_lo = v >> 63;
      }
    }
}

// Along y, rows of e in slices [z0, z1): the row below as it was is kept.
void DilateAlongY(BoxBits& d, const BitRegion& e, const BitRegion& g, int z0, int z1) {
  const int ww = g.w1 - g.w0 + 1;
  std::vector<uint64_t> prev(static_cast<size_t>(ww), 0), cur(prev);
  for (int zi = z0; zi < z1; ++zi) {
    if (e.y0 > 0) CopyWords(d.Row(e.y0 - 1, zi) + g.w0, ww, prev.data());
    for (int yi = e.y0; yi <= e.y1; ++yi) {
      uint64_t* r = d.Row(yi, zi) + g.w0;
      CopyWords(r, ww, cur.data());
      const uint64_t* before = yi > 0 ? prev.data() : kZeroWords;
      const uint64_t* next = yi + 1 < d.size.y ? d.Row(yi + 1, zi) + g.w0 : kZeroWords;
      for (int w = 0; w < ww; ++w) r[w] |= before[w] | next[w];
      prev.swap(cur);
    }
  }
}

// Along z, rows [y0, y1) of e's slices: the row of the slice below as it was
// is kept.
void DilateAlongZ(BoxBits& d, const BitRegion& e, const BitRegion& g, int y0, int y1) {
  const int ww = g.w1 - g.w0 + 1;
  std::vector<uint64_t> below(static_cast<size_t>(ww), 0), cur(below);
  for (int yi = y0; yi < y1; ++yi) {
    if (e.z0 > 0) CopyWords(d.Row(yi, e.z0 - 1) + g.w0, ww, below.data());
    for (int zi = e.z0; zi <= e.z1; ++zi) {
      uint64_t* r = d.Row(yi, zi) + g.w0;
      CopyWords(r, ww, cur.data());
      const uint64_t* under = zi > 0 ? below.data() : kZeroWords;
      const uint64_t* above = zi + 1 < d.size.z ? d.Row(yi, zi + 1) + g.w0 : kZeroWords;
      for (int w = 0; w < ww; ++w) r[w] |= under[w] | above[w];
      below.swap(cur);
    }
  }
}

// Grows `d` by one voxel in the 26-neighbourhood (clipped to the box),
// exactly inside `e` and to a subset of the grown set elsewhere (bits are
// only added, from neighbours), which is all ColumnRadii needs. Separable
// and in place: along x by shifting words (over e grown by one row, slice
// and word, what the y and z steps read), then along y and z by or-ing
// neighbour rows, the overwritten row kept in a small buffer. Each step
// reads only values from before it, so its rows (x), slices (y) or row
// positions (z) are independent and run in parallel: this is serial work
// of the transform otherwise, while the other thread may have none.
void DilateOnce(BoxBits& d, const BitRegion& e) {
  const BitRegion g = e.Grown(1, 1, d);
  using Range = tbb::blocked_range<int>;
  tbb::parallel_for(Range(g.z0, g.z1 + 1, 4),
                    [&](const Range& r) { DilateAlongX(d, g, r.begin(), r.end()); });
  // Along y for slices g.z0..g.z1 (the z step reads them), rows of e.
  tbb::parallel_for(Range(g.z0, g.z1 + 1, 4),
                    [&](const Range& r) { DilateAlongY(d, e, g, r.begin(), r.end()); });
  tbb::parallel_for(Range(e.y0, e.y1 + 1, 4),
                    [&](const Range& r) { DilateAlongZ(d, e, g, r.begin(), r.end()); });
}

// Bits of `qb` not in `d` over `region`, or-ed per (y, word) into `open`
// (which the caller cleared); returns the region where any were found.
// Rows of y run in parallel: each owns its words of `open`.
BitRegion OpenQueries(const BoxBits& qb, const BoxBits& d, const BitRegion& region,
                      std::vector<uint64_t>& open) {
  return tbb::parallel_reduce(
      tbb::blocked_range<int>(region.y0, region.y1 + 1, 4), BitRegion{},
      [&](const tbb::blocked_range<int>& range, BitRegion found) {
        for (int yi = range.begin(); yi < range.end(); ++yi)
          for (int zi = region.z0; zi <= region.z1; ++zi) {
            const uint64_t* qr = qb.bits.data() + (size_t(zi) * qb.size.y + yi) * qb.nw;
            const uint64_t* dr = d.bits.data() + (size_t(zi) * d.size.y + yi) * d.nw;
            for (int w = region.w0; w <= region.w1; ++w) {
              const uint64_t u = qr[w] & ~dr[w];
              open[size_t(yi) * qb.nw + w] |= u;
              if (u) found.Add(yi, zi, w);
            }
          }
        return found;
      },
      [](BitRegion a, const BitRegion& b) {
        if (b.Empty()) return a;
        a.Add(b.y0, b.z0, b.w0);
        a.Add(b.y1, b.z1, b.w1);
        return a;
      });
}

// For every (x, y) column of the box, a Chebyshev radius r such that each
// query of the column lies within r voxels (per axis) of a member, or -1
// when that takes more than max_r (radius[y * size.x + x]). The set is
// grown one voxel at a time; a column's radius is the first growth that
// covers all its queries. Queries covered once stay covered, so each round
// looks only at the region of the queries still open, and the growth is
// computed exactly only where later rounds can look (that region, widened
// by the growths left); elsewhere the grown set may lag, never run ahead.
void ColumnRadii(const VoxelSet& set, const VoxelSet& q, const VoxelBox& box, int max_r,
                 std::vector<int>& radius) {
  BoxBits d = CopyBits(set, box);
  const BoxBits qb = CopyBits(q, box);
  const Int3 b = box.Size();
  radius.assign(size_t(b.x) * b.y, 0);
  std::vector<uint64_t> open(size_t(qb.nw) * b.y);
  BitRegion region{0, b.y - 1, 0, b.z - 1, 0, qb.nw - 1};  // holds every open query
  for (int r = 1; r <= max_r + 1; ++r) {
    // Columns with a query outside the set grown by r - 1 need at least r.
    std::fill(open.begin(), open.end(), 0);
    const BitRegion found = OpenQueries(qb, d, region, open);
    if (found.Empty()) return;
    for (int yi = found.y0; yi <= found.y1; ++yi)
      for (int w = found.w0; w <= found.w1; ++w)
        for (uint64_t bits = open[size_t(yi) * qb.nw + w]; bits; bits &= bits - 1) {
          const int xi = ((qb.w0 + w) << 6) + std::countr_zero(bits) - box.min.x;
          if (xi >= 0 && xi < b.x) radius[size_t(yi) * b.x + xi] = r > max_r ? -1 : r;
        }
    // Later rounds read the grown set only at the open queries, after at
    // most max_r - r more growths: within max_r + 1 - r voxels of them.
    region = found;
    if (r <= max_r) DilateOnce(d, found.Grown(max_r + 1 - r, 1, d));
  }
}

// How far along axis a (integer weight k_a) a site may lie from a query
// and still be its nearest, when the query has a member within Chebyshev
// radius r: that member is at squared distance at most U = r^2 (k_x + k_y +
// k_z) (in units of the common power of two), so a site more than
// sqrt(U / k_a) voxels away along a is strictly worse, and so is a pass-2
// value computed without the sites beyond that reach (it is then either
// exact or above U). With exact arithmetic the envelope walk returns the
// lowest-position site among the minima, so dropping sites that are
// strictly worse at every query changes no result, ties included.
int SiteReach(Int3 k, int r, int ka) {
  const int64_t u = int64_t(r) * r * (int64_t(k.x) + k.y + k.z);
  int64_t l = int64_t(std::sqrt(double(u) / double(ka)));
  while ((l + 1) * (l + 1) * ka <= u) ++l;
  while (l * l * ka > u) --l;
  return int(l);
}

// RowsFromColumns for the columns of one x; lo, hi and reach are scratch of
// b.z entries.
void ColumnsOfX(Int3 b, Int3 k, const std::vector<int>& radius, int xi, std::vector<int>& lo,
                std::vector<int>& hi, std::vector<int>& reach, NeedRanges& need) {
  std::fill(lo.begin(), lo.end(), b.y);
  std::fill(hi.begin(), hi.end(), 0);
  std::fill(reach.begin(), reach.end(), 0);
  int all_lo = b.y, all_hi = 0;  // rows of unbounded columns
  for (int yi = 0; yi < b.y; ++yi) {
    const size_t c = size_t(yi) * b.x + xi;
    if (need.zlo[c] >= need.zhi[c]) continue;
    const int r = radius.empty() ? -1 : radius[c];
    if (r < 0) {
      all_lo = std::min(all_lo, yi);
      all_hi = yi + 1;
      continue;
    }
    const int ry = SiteReach(k, r, k.y), rz = SiteReach(k, r, k.z);
    need.reach_z[c] = rz;
    const int z1 = std::max(0, need.zlo[c] - rz), z2 = std::min(b.z, need.zhi[c] + rz);
    for (int zi = z1; zi < z2; ++zi) {
      lo[size_t(zi)] = std::min(lo[size_t(zi)], yi);
      hi[size_t(zi)] = std::max(hi[size_t(zi)], yi + 1);
      reach[size_t(zi)] = std::max(reach[size_t(zi)], ry);
    }
  }
  // Unbounded columns reach every slice with every site.
  for (int zi = 0; zi < b.z; ++zi) {
    const size_t i = size_t(zi) * b.x + xi;
    const size_t z = size_t(zi);
    if (all_lo < all_hi) {
      need.ylo[i] = std::min(lo[z], all_lo);
      need.yhi[i] = std::max(hi[z], all_hi);
      need.reach_y[i] = b.y;
    } else if (lo[z] < hi[z]) {
      need.ylo[i] = lo[z];
      need.yhi[i] = hi[z];
      need.reach_y[i] = reach[z];
    }
  }
}

// Site reaches from the column radii (-1 or none: unbounded), then the
// pass-2 rows from the pass-3 columns: slice z of column x needs row y when
// (x, y) has queries whose slice range, widened by the column's reach,
// holds z; the pass-2 line takes the largest reach along y of those columns.
// Unbounded columns reach every slice, so they are merged per x at the end
// (one pass over the lines instead of one per column).
void RowsFromColumns(Int3 b, Int3 k, const std::vector<int>& radius, NeedRanges& need) {
  // Per x, lines by slice (lo, hi, reach), so the loop over a column's
  // slices below is contiguous and branch-free; yi grows, so the min and
  // max give the first and last column exactly as in row order.
  // Each x writes only its own entries, so runs of x go in parallel.
  need.ylo.assign(size_t(b.x) * b.z, 0);
  need.yhi.assign(size_t(b.x) * b.z, 0);
  need.reach_y.assign(size_t(b.x) * b.z, 0);
  need.reach_z.assign(size_t(b.x) * b.y, b.z);
  tbb::parallel_for(tbb::blocked_range<int>(0, b.x, 16), [&](const tbb::blocked_range<int>& xs) {
    std::vector<int> lo(static_cast<size_t>(b.z)), hi(lo), reach(lo);
    for (int xi = xs.begin(); xi < xs.end(); ++xi)
      ColumnsOfX(b, k, radius, xi, lo, hi, reach, need);
  });
  SliceRows(b, need);
}

// The ranges from the query voxels inside `box`. Two word-level sweeps
// along z (up, then down) find each column's first and last query, so the
// bit-level work is per (x, y) column rather than per query voxel.
void QueryRanges(const VoxelSet& q, const VoxelBox& box, NeedRanges& need) {
  const Int3 b = box.Size();
  const int w0 = box.min.x >> 6, w1 = box.max.x >> 6, nw = w1 - w0 + 1;
  need.zlo.assign(size_t(b.x) * b.y, 0);
  need.zhi.assign(size_t(b.x) * b.y, 0);
  std::vector<uint64_t> inside(size_t(nw), ~uint64_t{0});  // bits of a row inside the box
  inside[0] &= ~uint64_t{0} << (box.min.x & 63);
  if ((box.max.x & 63) != 63) inside[size_t(nw - 1)] &= (uint64_t{2} << (box.max.x & 63)) - 1;
  // Each row position y has its own columns, so they run in parallel.
  tbb::parallel_for(tbb::blocked_range<int>(0, b.y, 4), [&](const tbb::blocked_range<int>& ys) {
    std::vector<uint64_t> seen(static_cast<size_t>(nw));
    auto sweep = [&](int yi, int z_first, int z_step, std::vector<int>& bound, int offset) {
      std::fill(seen.begin(), seen.end(), 0);
      for (int zi = z_first; zi >= 0 && zi < b.z; zi += z_step) {
        const uint64_t* row = q.Row(box.min.y + yi, box.min.z + zi) + w0;
        for (int w = 0; w < nw; ++w) {
          const uint64_t fresh = row[w] & inside[size_t(w)] & ~seen[size_t(w)];
          if (!fresh) continue;
          seen[size_t(w)] |= fresh;
          for (uint64_t bits = fresh; bits; bits &= bits - 1) {
            const int xi = ((w0 + w) << 6) + std::countr_zero(bits) - box.min.x;
            bound[size_t(yi) * b.x + xi] = zi + offset;
          }
        }
      }
    };
    for (int yi = ys.begin(); yi < ys.end(); ++yi) {
      sweep(yi, 0, 1, need.zlo, 0);
      sweep(yi, b.z - 1, -1, need.zhi, 1);
    }
  });
}

// The positions [lo, hi) some column of a block of `nb` columns needs
// (column j needs [lo_of[j], hi_of[j])), of `n` along the line, and the
// block's largest reach; lo >= hi when no column needs any.
struct BlockRange {
  int lo, hi, reach;
};
BlockRange BlockNeed(const int* lo_of, const int* hi_of, const int* reach_of, int nb, int n) {
  BlockRange r{n, 0, 0};
  for (int j = 0; j < nb; ++j)
    if (lo_of[j] < hi_of[j]) {
      r.lo = std::min(r.lo, lo_of[j]);
      r.hi = std::max(r.hi, hi_of[j]);
    }
  for (int j = 0; j < nb; ++j) r.reach = std::max(r.reach, reach_of[j]);
  return r;
}

// Which parts of the last two passes the queries of `options` need inside
// `box` (all of them without queries).
NeedRanges NeededRanges(const VoxelSet& set, Vec3 h, const FeatureTransformOptions& options,
                        const VoxelBox& box) {
  const Int3 b = box.Size();
  NeedRanges need;
  if (options.queries) {
    QueryRanges(*options.queries, box, need);
    // Queries close to the set (the usual case in a median iteration) bound
    // how far the useful sites lie; past kMaxRadius the test costs more than
    // it saves, and the lines keep all their sites.
    constexpr int kMaxRadius = 8;
    const std::optional<Int3> k = ExactWeights(h.x * h.x, h.y * h.y, h.z * h.z);
    std::vector<int> radius;  // empty: every column unbounded
    if (k) ColumnRadii(set, *options.queries, box, kMaxRadius, radius);
    RowsFromColumns(b, k.value_or(Int3{1, 1, 1}), radius, need);
  } else {
    AllRanges(b, need);
  }
  return need;
}

// @brief The three passes of ComputeFeatureTransform over one box, sharing
// the lattice, the ranges the queries need and the interrupter. Each pass
// runs in parallel and stops at the next slice or layer once interrupted.
class FeaturePasses {
 public:
  FeaturePasses(const VoxelSet& set, Vec3 h, const VoxelBox& box, const NeedRanges& need,
                PackedVoxel* F, Interrupter* interrupter)
      : set(set),
        box(box),
        need(need),
        F(F),
        intr(OrNull(interrupter)),
        b(box.Size()),
        x0(box.min.x),
        y0(box.min.y),
        z0(box.min.z),
        plane(size_t(b.x) * b.y),
        wx(h.x * h.x),
        wy(h.y * h.y),
        wz(h.z * h.z),
        work(uint64_t(b.z) * 2 + uint64_t(b.y)) {}

  absl::Status Run() {
    AlongX();
    if (cancelled) return absl::CancelledError("feature transform interrupted");
    CostTables();
    AlongY();
    if (cancelled) return absl::CancelledError("feature transform interrupted");
    AlongZ();
    if (cancelled) return absl::CancelledError("feature transform interrupted");
    return absl::OkStatus();
  }

 private:
  // Polled once per slice or layer (about a millisecond at 256^3), not per
  // TBB chunk: an auto-partitioned chunk can hold a large share of the lattice.
  bool keep_going() {
    if (cancelled.load(std::memory_order_relaxed)) return false;
    if (intr.WasInterrupted(done.fetch_add(1) + 1, work)) cancelled = true;
    return !cancelled.load(std::memory_order_relaxed);
  }

  // Pass 1, along x: nearest member within each row, run by run: members
  // map to themselves, and each gap between two members splits at its
  // midpoint (ties go left).
  void AlongX() {
    tbb::parallel_for(tbb::blocked_range<int>(0, b.z, 4), [&](const tbb::blocked_range<int>& r) {
      if (cancelled) return;
      const int x1 = box.max.x;
      for (int zi = r.begin(); zi < r.end() && keep_going(); ++zi) {
        const int z = z0 + zi;
        for (int yi = need.row_lo[size_t(zi)]; yi < need.row_hi[size_t(zi)]; ++yi) {
          const int y = y0 + yi;
          PackedVoxel* const at = F + size_t(zi) * plane + size_t(yi) * b.x - x0;  // by lattice x
          const uint64_t* row = set.Row(y, z);
          const PackedVoxel yz = PackVoxel(0, y, z);
          int pos = x0, prev = -1;  // next position to write; last member so far
          for (;;) {
            const int m = NextBit(row, pos, x1, 0);
            if (m > x1) break;
            const int e = NextBit(row, m, x1, ~uint64_t{0});  // end of the run
            const int split = prev < 0 ? pos - 1 : (prev + m) >> 1;
            for (int x = pos; x <= split; ++x) at[x] = yz | uint32_t(prev);
            for (int x = std::max(pos, split + 1); x < m; ++x) at[x] = yz | uint32_t(m);
            for (int x = m; x < e; ++x) at[x] = yz | uint32_t(x);
            prev = e - 1;
            pos = e;
          }
          if (prev < 0) {
            std::fill(at + x0, at + x1 + 1, kNoVoxel);
            continue;
          }
          for (int x = pos; x <= x1; ++x) at[x] = yz | uint32_t(prev);
        }
      }
    });
  }

  // w d^2 of every offset d along x and y (|d| < 1024, indexed by d + 1023):
  // the earlier axes' cost of a site, read instead of squared, converted and
  // multiplied per site (the same double either way); and w pos^2 of every
  // position of the last two passes, for EnvelopeLine.
  void CostTables() {
    wdd_x.resize(2047);
    wdd_y.resize(2047);
    for (int d = -1023; d <= 1023; ++d) {
      wdd_x[size_t(d + 1023)] = wx * Square(d);
      wdd_y[size_t(d + 1023)] = wy * Square(d);
    }
    cost_x = wdd_x.data() + 1023;
    cost_y = wdd_y.data() + 1023;
    wpp_y.resize(size_t(b.y));
    wpp_z.resize(size_t(b.z));
    for (int yi = 0; yi < b.y; ++yi) wpp_y[size_t(yi)] = wy * double(y0 + yi) * (y0 + yi);
    for (int zi = 0; zi < b.z; ++zi) wpp_z[size_t(zi)] = wz * double(z0 + zi) * (z0 + zi);
  }

  // Pass 2, along y: combine rows within each z slice. Pass 3 reads rows
  // [ylo, yhi) of column x only, so only those are written. Columns are
  // gathered kBlock at a time into a contiguous tile (one cache line per
  // row) instead of being walked a row stride apart.
  void AlongY() {
    constexpr int kBlock = kTileBlock;
    tbb::parallel_for(tbb::blocked_range<int>(0, b.z, 2), [&](const tbb::blocked_range<int>& r) {
      if (cancelled) return;
      LineScratch s;
      s.Reserve(b.y);
      std::vector<PackedVoxel> tile(size_t(b.y) * kBlock);
      std::vector<int> rows;  // rows of the slice with a member: the sites
      for (int zi = r.begin(); zi < r.end() && keep_going(); ++zi) {
        PackedVoxel* slice = F + size_t(zi) * plane;
        rows.clear();
        for (int yi = need.row_lo[size_t(zi)]; yi < need.row_hi[size_t(zi)]; ++yi)
          if (slice[size_t(yi) * b.x] != kNoVoxel) rows.push_back(yi);
        if (rows.empty()) continue;  // every column stays kNoVoxel
        const int* ylo = need.ylo.data() + size_t(zi) * b.x;
        const int* yhi = need.yhi.data() + size_t(zi) * b.x;
        const int* ry = need.reach_y.data() + size_t(zi) * b.x;
        // Sites of rows [first, last) of the slice's site list.
        auto sites_between = [&](int from, int to) {
          const int first = int(std::lower_bound(rows.begin(), rows.end(), from) - rows.begin());
          const int last = int(std::lower_bound(rows.begin(), rows.end(), to) - rows.begin());
          return std::pair<int, int>{first, last};
        };
        for (int xb = 0; xb < b.x; xb += kBlock) {
          const int nb = std::min(kBlock, b.x - xb);
          // The tile needs the site rows within reach and the rows written back.
          const auto [lo, hi, reach] = BlockNeed(ylo + xb, yhi + xb, ry + xb, nb, b.y);
          if (lo >= hi) continue;
          const auto [s0, s1] = sites_between(lo - reach, hi + reach);
          for (int i = s0; i < s1; ++i) {
            const int yi = rows[size_t(i)];
            if (yi < lo || yi >= hi)
              CopyRow<kBlock>(slice + size_t(yi) * b.x + xb, nb, tile.data() + size_t(yi) * kBlock);
          }
          for (int yi = lo; yi < hi; ++yi)
            CopyRow<kBlock>(slice + size_t(yi) * b.x + xb, nb, tile.data() + size_t(yi) * kBlock);
          for (int j = 0; j < nb; ++j) {
            if (ylo[xb + j] >= yhi[xb + j]) continue;
            const int x = x0 + xb + j;
            PackedVoxel* col = tile.data() + j;
            const auto [i0, i1] = sites_between(ylo[xb + j] - ry[xb + j], yhi[xb + j] + ry[xb + j]);
            if (i0 >= i1) continue;  // no site within reach: no query reads these rows
            const int m = i1 - i0;
            for (int i = 0; i < m; ++i) {
              const int yi = rows[size_t(i0 + i)];
              const PackedVoxel f = col[size_t(yi) * kBlock];
              s.pos[i] = y0 + yi;
              s.c[i] = cost_x[int(f & 1023u) - x] + wpp_y[size_t(yi)];
              s.f[i] = f;
            }
            EnvelopeLine(s, m, wy, y0, ylo[xb + j], yhi[xb + j], col, kBlock);
          }
          for (int yi = lo; yi < hi; ++yi)
            CopyRow<kBlock>(tile.data() + size_t(yi) * kBlock, nb, slice + size_t(yi) * b.x + xb);
        }
      }
    });
  }

  // Pass 3, along z: combine slices within each y layer, writing only the
  // z range each column's queries need. Columns are gathered as in pass 2,
  // so each slice row read brings in a whole cache line instead of one value
  // per far-apart page.
  void AlongZ() {
    constexpr int kBlock = kTileBlock;
    tbb::parallel_for(tbb::blocked_range<int>(0, b.y, 2), [&](const tbb::blocked_range<int>& r) {
      if (cancelled) return;
      LineScratch s;
      s.Reserve(b.z);
      std::vector<PackedVoxel> tile(size_t(b.z) * kBlock);
      for (int yi = r.begin(); yi < r.end() && keep_going(); ++yi) {
        const int y = y0 + yi;
        PackedVoxel* layer = F + size_t(yi) * b.x;
        const int* zlo = need.zlo.data() + size_t(yi) * b.x;
        const int* zhi = need.zhi.data() + size_t(yi) * b.x;
        const int* rz = need.reach_z.data() + size_t(yi) * b.x;
        for (int xb = 0; xb < b.x; xb += kBlock) {
          const int nb = std::min(kBlock, b.x - xb);
          // Sites lie within reach of the slices written (see SiteReach).
          const auto [lo, hi, reach] = BlockNeed(zlo + xb, zhi + xb, rz + xb, nb, b.z);
          if (lo >= hi) continue;
          for (int zi = std::max(0, lo - reach); zi < std::min(b.z, hi + reach); ++zi)
            CopyRow<kBlock>(layer + size_t(zi) * plane + xb, nb, tile.data() + size_t(zi) * kBlock);
          for (int j = 0; j < nb; ++j) {
            if (zlo[xb + j] >= zhi[xb + j]) continue;
            const int x = x0 + xb + j;
            PackedVoxel* col = tile.data() + j;
            int m = 0;
            const int z2 = std::min(b.z, zhi[xb + j] + rz[xb + j]);
            for (int zi = std::max(0, zlo[xb + j] - rz[xb + j]); zi < z2; ++zi) {
              const PackedVoxel f = col[size_t(zi) * kBlock];
              if (f == kNoVoxel) continue;
              s.pos[m] = z0 + zi;
              s.c[m] = (cost_x[int(f & 1023u) - x] + cost_y[int((f >> 10) & 1023u) - y]) +
                       wpp_z[size_t(zi)];
              s.f[m] = f;
              ++m;
            }
            if (m > 0) EnvelopeLine(s, m, wz, z0, zlo[xb + j], zhi[xb + j], col, kBlock);
          }
          for (int zi = lo; zi < hi; ++zi)
            CopyRow<kBlock>(tile.data() + size_t(zi) * kBlock, nb, layer + size_t(zi) * plane + xb);
        }
      }
    });
  }

  static constexpr int kTileBlock = 16;
  const VoxelSet& set;
  const VoxelBox box;
  const NeedRanges& need;
  PackedVoxel* const F;
  Interrupter& intr;
  const Int3 b;
  const int x0, y0, z0;
  const size_t plane;
  const double wx, wy, wz;
  const uint64_t work;
  std::atomic<bool> cancelled{false};
  std::atomic<uint64_t> done{0};
  std::vector<double> wdd_x, wdd_y, wpp_y, wpp_z;
  const double* cost_x = nullptr;
  const double* cost_y = nullptr;
};

}  // namespace

absl::Status ComputeFeatureTransform(const VoxelSet& set, Vec3 h,
                                     const FeatureTransformOptions& options, FeatureField& out,
                                     Interrupter* interrupter) {
  const Int3 res = set.resolution();
  if (!(h.x > 0 && h.y > 0 && h.z > 0) || !IsFinite(h))
    return absl::InvalidArgumentError("feature transform: voxel sizes must be positive");
  VoxelBox box = options.box.value_or(VoxelBox{{0, 0, 0}, {res.x - 1, res.y - 1, res.z - 1}});
  if (box.min.x < 0 || box.min.y < 0 || box.min.z < 0 || box.max.x >= res.x || box.max.y >= res.y ||
      box.max.z >= res.z || box.min.x > box.max.x || box.min.y > box.max.y ||
      box.min.z > box.max.z) {
    return absl::InvalidArgumentError("feature transform: box outside the lattice");
  }
  const std::optional<VoxelBox> members = options.set_box ? options.set_box : set.BoundingBox();
  if (members) box = VoxelBox::Hull(box, *members);
  out.box = box;
  const Int3 b = box.Size();
  const size_t total = size_t(b.x) * b.y * b.z;
  // Growing through clear() copies nothing: pass 1 writes every entry.
  if (out.nearest.capacity() < total) out.nearest.clear();
  out.nearest.resize(total);
  if (!members) {
    std::fill(out.nearest.begin(), out.nearest.end(), kNoVoxel);
    return absl::OkStatus();
  }
  const NeedRanges need = NeededRanges(set, h, options, box);
  return FeaturePasses(set, h, box, need, out.nearest.data(), interrupter).Run();
}

absl::StatusOr<FeatureField> ComputeFeatureTransform(const VoxelSet& set, Vec3 voxel_size,
                                                     Interrupter* interrupter) {
  FeatureField field;
  absl::Status s = ComputeFeatureTransform(set, voxel_size, {}, field, interrupter);
  if (!s.ok()) return s;
  return field;
}

absl::StatusOr<double> DirectedHausdorff(const VoxelSet& a, const VoxelSet& b, Vec3 h,
                                         Interrupter* interrupter) {
  if (!(a.resolution() == b.resolution()))
    return absl::InvalidArgumentError("Hausdorff distance: sets differ in resolution");
  if (a.Empty()) return 0.0;
  if (b.Empty()) return kInf;
  const VoxelSet outside = a - b;
  if (outside.Empty()) return 0.0;
  FeatureTransformOptions opt;
  opt.box = outside.BoundingBox();
  opt.queries = &outside;
  FeatureField field;
  NIMBUS_RETURN_IF_ERROR(ComputeFeatureTransform(b, h, opt, field, interrupter));
  double worst = 0;
  outside.ForEach([&](int x, int y, int z) {
    worst = std::max(worst, SquaredDistance({x, y, z}, UnpackVoxel(field.At(x, y, z)), h));
  });
  return std::sqrt(worst);
}

absl::StatusOr<double> HausdorffDistance(const VoxelSet& a, const VoxelSet& b, Vec3 h,
                                         Interrupter* interrupter) {
  NIMBUS_ASSIGN_OR_RETURN(const double ab, DirectedHausdorff(a, b, h, interrupter));
  NIMBUS_ASSIGN_OR_RETURN(const double ba, DirectedHausdorff(b, a, h, interrupter));
  return std::max(ab, ba);
}

}  // namespace nimbus
