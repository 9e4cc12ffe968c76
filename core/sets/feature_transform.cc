#include "core/sets/feature_transform.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

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
  std::vector<int> hp;
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
  int* hp = s.hp.data();
  PackedVoxel* hf = s.hf.data();
  int k = 0;
  hc[0] = c[0];
  hp[0] = p[0];
  hf[0] = f[0];
  for (int i = 1; i < m; ++i) {
    const double ci = c[i];
    const int pi = p[i];
    // Pop the top while the new parabola overtakes it no later than it
    // overtakes the one below.
    while (k > 0) {
      if ((hc[k] - hc[k - 1]) * double(pi - hp[k]) < (ci - hc[k]) * double(hp[k] - hp[k - 1]))
        break;
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
  int h = 0, i = lo;
  while (h < k && i < hi) {
    const double dc = hc[h + 1] - hc[h], dp = double(hp[h + 1] - hp[h]);
    const PackedVoxel fu = hf[h];
    // Positions where the next parabola is not strictly lower stay with u.
    for (; i < hi && !(dc < 2.0 * w * (q0 + i) * dp); ++i) out[size_t(i) * stride] = fu;
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
// [ylo[x], yhi[x]) of each x column in every slice (pass 2) and slices
// [zlo, zhi) of each (x, y) column (pass 3, indexed y * size.x + x). An
// empty range (lo >= hi) means the column is not needed.
struct NeedRanges {
  std::vector<int> ylo, yhi, zlo, zhi;
};

void AllRanges(Int3 b, NeedRanges& need) {
  need.ylo.assign(size_t(b.x), 0);
  need.yhi.assign(size_t(b.x), b.y);
  need.zlo.assign(size_t(b.x) * b.y, 0);
  need.zhi.assign(size_t(b.x) * b.y, b.z);
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
  std::vector<uint64_t> seen(size_t(b.y) * nw);
  auto sweep = [&](int z_first, int z_step, std::vector<int>& bound, int offset) {
    std::fill(seen.begin(), seen.end(), 0);
    for (int zi = z_first; zi >= 0 && zi < b.z; zi += z_step)
      for (int yi = 0; yi < b.y; ++yi) {
        const uint64_t* row = q.Row(box.min.y + yi, box.min.z + zi) + w0;
        uint64_t* s = seen.data() + size_t(yi) * nw;
        for (int w = 0; w < nw; ++w) {
          const uint64_t fresh = row[w] & inside[size_t(w)] & ~s[w];
          if (!fresh) continue;
          s[w] |= fresh;
          for (uint64_t bits = fresh; bits; bits &= bits - 1) {
            const int xi = ((w0 + w) << 6) + std::countr_zero(bits) - box.min.x;
            bound[size_t(yi) * b.x + xi] = zi + offset;
          }
        }
      }
  };
  sweep(0, 1, need.zlo, 0);
  sweep(b.z - 1, -1, need.zhi, 1);
  need.ylo.assign(size_t(b.x), 0);
  need.yhi.assign(size_t(b.x), 0);
  for (int yi = 0; yi < b.y; ++yi)
    for (int xi = 0; xi < b.x; ++xi) {
      const size_t i = size_t(yi) * b.x + xi;
      if (need.zlo[i] >= need.zhi[i]) continue;
      if (need.ylo[xi] >= need.yhi[xi]) need.ylo[xi] = yi;
      need.yhi[xi] = yi + 1;
    }
}

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
  const std::optional<VoxelBox> members = set.BoundingBox();
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

  const double wx = h.x * h.x, wy = h.y * h.y, wz = h.z * h.z;
  const int x0 = box.min.x, y0 = box.min.y, z0 = box.min.z;
  const size_t plane = size_t(b.x) * b.y;
  PackedVoxel* const F = out.nearest.data();

  // Which parts of the last two passes the queries need.
  NeedRanges need;
  if (options.queries)
    QueryRanges(*options.queries, box, need);
  else
    AllRanges(b, need);

  Interrupter& intr = OrNull(interrupter);
  std::atomic<bool> cancelled{false};
  std::atomic<uint64_t> done{0};
  const uint64_t work = uint64_t(b.z) * 2 + uint64_t(b.y);
  // Polled once per slice or layer (about a millisecond at 256^3), not per
  // TBB chunk: an auto-partitioned chunk can hold a large share of the lattice.
  auto keep_going = [&] {
    if (cancelled.load(std::memory_order_relaxed)) return false;
    if (intr.WasInterrupted(done.fetch_add(1) + 1, work)) cancelled = true;
    return !cancelled.load(std::memory_order_relaxed);
  };

  // Pass 1, along x: nearest member within each row, run by run: members
  // map to themselves, and each gap between two members splits at its
  // midpoint (ties go left).
  tbb::parallel_for(tbb::blocked_range<int>(0, b.z, 4), [&](const tbb::blocked_range<int>& r) {
    if (cancelled) return;
    const int x1 = box.max.x;
    for (int zi = r.begin(); zi < r.end() && keep_going(); ++zi) {
      const int z = z0 + zi;
      for (int yi = 0; yi < b.y; ++yi) {
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
  if (cancelled) return absl::CancelledError("feature transform interrupted");

  // w pos^2 of every position of the last two passes, for EnvelopeLine.
  std::vector<double> wpp_y(size_t(b.y)), wpp_z(size_t(b.z));
  for (int yi = 0; yi < b.y; ++yi) wpp_y[size_t(yi)] = wy * double(y0 + yi) * (y0 + yi);
  for (int zi = 0; zi < b.z; ++zi) wpp_z[size_t(zi)] = wz * double(z0 + zi) * (z0 + zi);

  // Pass 2, along y: combine rows within each z slice. Pass 3 reads rows
  // [ylo, yhi) of column x only, so only those are written. Columns are
  // gathered kBlock at a time into a contiguous tile (one cache line per
  // row) instead of being walked a row stride apart.
  constexpr int kBlock = 16;
  tbb::parallel_for(tbb::blocked_range<int>(0, b.z, 2), [&](const tbb::blocked_range<int>& r) {
    if (cancelled) return;
    LineScratch s;
    s.Reserve(b.y);
    std::vector<PackedVoxel> tile(size_t(b.y) * kBlock);
    std::vector<int> rows;  // rows of the slice with a member: the sites
    for (int zi = r.begin(); zi < r.end() && keep_going(); ++zi) {
      PackedVoxel* slice = F + size_t(zi) * plane;
      rows.clear();
      for (int yi = 0; yi < b.y; ++yi)
        if (slice[size_t(yi) * b.x] != kNoVoxel) rows.push_back(yi);
      if (rows.empty()) continue;  // every column stays kNoVoxel
      const int m = int(rows.size());
      for (int i = 0; i < m; ++i) s.pos[i] = y0 + rows[size_t(i)];
      for (int xb = 0; xb < b.x; xb += kBlock) {
        const int nb = std::min(kBlock, b.x - xb);
        int lo = b.y, hi = 0;  // rows some column of the block needs
        for (int j = 0; j < nb; ++j)
          if (need.ylo[xb + j] < need.yhi[xb + j]) {
            lo = std::min(lo, need.ylo[xb + j]);
            hi = std::max(hi, need.yhi[xb + j]);
          }
        if (lo >= hi) continue;
        // The tile needs the site rows and the rows written back.
        for (int yi : rows)
          if (yi < lo || yi >= hi)
            CopyRow<kBlock>(slice + size_t(yi) * b.x + xb, nb, tile.data() + size_t(yi) * kBlock);
        for (int yi = lo; yi < hi; ++yi)
          CopyRow<kBlock>(slice + size_t(yi) * b.x + xb, nb, tile.data() + size_t(yi) * kBlock);
        for (int j = 0; j < nb; ++j) {
          if (need.ylo[xb + j] >= need.yhi[xb + j]) continue;
          const int x = x0 + xb + j;
          PackedVoxel* col = tile.data() + j;
          for (int i = 0; i < m; ++i) {
            const PackedVoxel f = col[size_t(rows[size_t(i)]) * kBlock];
            s.c[i] = wx * Square(int(f & 1023u) - x) + wpp_y[size_t(rows[size_t(i)])];
            s.f[i] = f;
          }
          EnvelopeLine(s, m, wy, y0, need.ylo[xb + j], need.yhi[xb + j], col, kBlock);
        }
        for (int yi = lo; yi < hi; ++yi)
          CopyRow<kBlock>(tile.data() + size_t(yi) * kBlock, nb, slice + size_t(yi) * b.x + xb);
      }
    }
  });
  if (cancelled) return absl::CancelledError("feature transform interrupted");

  // Pass 3, along z: combine slices within each y layer, writing only the
  // z range each column's queries need. Columns are gathered as in pass 2,
  // so each slice row read brings in a whole cache line instead of one value
  // per far-apart page.
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
      for (int xb = 0; xb < b.x; xb += kBlock) {
        const int nb = std::min(kBlock, b.x - xb);
        int lo = b.z, hi = 0;  // slices some column of the block needs
        for (int j = 0; j < nb; ++j)
          if (zlo[xb + j] < zhi[xb + j]) {
            lo = std::min(lo, zlo[xb + j]);
            hi = std::max(hi, zhi[xb + j]);
          }
        if (lo >= hi) continue;
        for (int zi = 0; zi < b.z; ++zi)
          CopyRow<kBlock>(layer + size_t(zi) * plane + xb, nb, tile.data() + size_t(zi) * kBlock);
        for (int j = 0; j < nb; ++j) {
          if (zlo[xb + j] >= zhi[xb + j]) continue;
          const int x = x0 + xb + j;
          PackedVoxel* col = tile.data() + j;
          int m = 0;
          for (int zi = 0; zi < b.z; ++zi) {
            const PackedVoxel f = col[size_t(zi) * kBlock];
            if (f == kNoVoxel) continue;
            s.pos[m] = z0 + zi;
            s.c[m] = (wx * Square(int(f & 1023u) - x) + wy * Square(int((f >> 10) & 1023u) - y)) +
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
  if (cancelled) return absl::CancelledError("feature transform interrupted");
  return absl::OkStatus();
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
