#include "core/sets/set_maps.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <optional>
#include <vector>

#include "absl/strings/str_cat.h"
#include "core/base/random.h"
#include "core/base/status_macros.h"

namespace nimbus {
namespace {

using Clock = std::chrono::steady_clock;

double SecondsSince(Clock::time_point t) {
  return std::chrono::duration<double>(Clock::now() - t).count();
}

// Sets a voxel from any thread. Skips the locked instruction when the bit
// is already there, which is common: the median contracts many voxels onto
// few.
inline void SetAtomic(VoxelSet& set, int x, int y, int z) {
  uint64_t& word = set.MutableRow(y, z)[x >> 6];
  const uint64_t bit = uint64_t{1} << (x & 63);
  std::atomic_ref<uint64_t> ref(word);
  if (!(ref.load(std::memory_order_relaxed) & bit)) ref.fetch_or(bit, std::memory_order_relaxed);
}

inline bool GetAtomic(VoxelSet& set, int x, int y, int z) {
  std::atomic_ref<uint64_t> ref(set.MutableRow(y, z)[x >> 6]);
  return (ref.load(std::memory_order_relaxed) >> (x & 63)) & 1;
}

// Halfway from a to f. Where a coordinate sum is odd the midpoint sits on
// a voxel face; bit i of `round_up` sends it up along axis i, else down.
// The choice is per application, not per voxel: rounding stays monotone,
// so neighbouring images never part by rounding alone, while drawing the
// bits from the seed keeps the median unbiased over an iteration and lets a
// voxel next to its target step onto it in half of the applications (fixed
// rounding would park such voxels one voxel off the condensation set).
// It depends on a + f only, so D stays symmetric in its two voxels.
inline Int3 Midpoint(Int3 a, Int3 f, unsigned round_up) {
  return {(a.x + f.x + int(round_up & 1)) >> 1, (a.y + f.y + int((round_up >> 1) & 1)) >> 1,
          (a.z + f.z + int((round_up >> 2) & 1)) >> 1};
}

inline int Chebyshev(Int3 a, Int3 b) {
  return std::max({std::abs(a.x - b.x), std::abs(a.y - b.y), std::abs(a.z - b.z)});
}

inline Int3 Add(Int3 a, Int3 b) { return {a.x + b.x, a.y + b.y, a.z + b.z}; }

// True when the nearest-point map looks continuous between nearby source
// voxels a and n (with nearest points fa, fn). Two moving voxels must move
// in directions at most 60 degrees apart: across a medial axis of the
// target they move apart, a tear the exact image has too. A voxel that does
// not move (it is in the target) agrees with a moving one unless that one
// moves away from it, which again means a medial axis runs between them.
inline bool Coherent(Int3 a, Int3 fa, Int3 n, Int3 fn) {
  const int64_t ux = fa.x - a.x, uy = fa.y - a.y, uz = fa.z - a.z;
  const int64_t vx = fn.x - n.x, vy = fn.y - n.y, vz = fn.z - n.z;
  const int64_t uu = ux * ux + uy * uy + uz * uz, vv = vx * vx + vy * vy + vz * vz;
  if (uu == 0 && vv == 0) return true;
  if (vv == 0) return ux * (n.x - a.x) + uy * (n.y - a.y) + uz * (n.z - a.z) >= 0;
  if (uu == 0) return vx * (a.x - n.x) + vy * (a.y - n.y) + vz * (a.z - n.z) >= 0;
  const int64_t dot = ux * vx + uy * vy + uz * vz;
  return dot > 0 && 4 * dot * dot >= uu * vv;
}

// Sets every voxel whose index lies in the closed tetrahedron p[0..3]
// (exact integer tests, so tetrahedra sharing a face leave no crack).
void FillTetrahedron(const Int3 p[4], VoxelSet& out) {
  auto orient = [](Int3 a, Int3 b, Int3 c, Int3 d) {
    const int64_t bx = b.x - a.x, by = b.y - a.y, bz = b.z - a.z;
    const int64_t cx = c.x - a.x, cy = c.y - a.y, cz = c.z - a.z;
    const int64_t dx = d.x - a.x, dy = d.y - a.y, dz = d.z - a.z;
    return bx * (cy * dz - cz * dy) - by * (cx * dz - cz * dx) + bz * (cx * dy - cy * dx);
  };
  const int64_t vol = orient(p[0], p[1], p[2], p[3]);
  if (vol == 0) return;  // flat: the edge bridges cover it
  Int3 lo = p[0], hi = p[0];
  for (int i = 1; i < 4; ++i) {
    lo = {std::min(lo.x, p[i].x), std::min(lo.y, p[i].y), std::min(lo.z, p[i].z)};
    hi = {std::max(hi.x, p[i].x), std::max(hi.y, p[i].y), std::max(hi.z, p[i].z)};
  }
  for (int z = lo.z; z <= hi.z; ++z)
    for (int y = lo.y; y <= hi.y; ++y)
      for (int x = lo.x; x <= hi.x; ++x) {
        const Int3 v{x, y, z};
        if (!out.InBounds(v) || GetAtomic(out, x, y, z)) continue;
        // v is inside when replacing any corner by v keeps the orientation.
        const int64_t s0 = orient(v, p[1], p[2], p[3]), s1 = orient(p[0], v, p[2], p[3]);
        const int64_t s2 = orient(p[0], p[1], v, p[3]), s3 = orient(p[0], p[1], p[2], v);
        const bool inside = vol > 0 ? (s0 >= 0 && s1 >= 0 && s2 >= 0 && s3 >= 0)
                                    : (s0 <= 0 && s1 <= 0 && s2 <= 0 && s3 <= 0);
        if (inside) SetAtomic(out, x, y, z);
      }
}

absl::Status CheckPair(const VoxelSet& a, const VoxelSet& b, const GridFrame& frame) {
  NIMBUS_RETURN_IF_ERROR(ValidateSetFrame(frame));
  if (!(a.resolution() == frame.resolution) || !(b.resolution() == frame.resolution))
    return absl::InvalidArgumentError("set map: set resolution differs from the grid frame");
  return absl::OkStatus();
}

// Adds { Midpoint(a, nearest(a)) : a in moving } to `out`, where `moving`
// is the part of `source` outside the target set and `field` holds nearest
// target voxels at least at every moving voxel. Members of `source` that
// are not moving lie in the target and map to themselves.
//
// Gap filling: where the images of face-adjacent voxels are two or more
// voxels apart but their nearest points are close and in agreeing
// directions (the nearest-point map is continuous there, so the exact image
// is solid), the segment between the images is drawn, and the image of the
// voxel cube spanned from `a` is filled as six tetrahedra.
absl::Status AddMidpoints(const VoxelSet& moving, const VoxelSet& source, const FeatureField& field,
                          const MedianOptions& options, uint64_t seed,
                          const VoxelBox& moving_box, decltype(SetMapWorkspace::images)& images,
                          VoxelSet& out, Interrupter& intr) {
  const Int3 res = moving.resolution();
  const unsigned round_up = unsigned(Mix64(seed) >> 61);
  const int jump = options.bridge_max_jump;
  const VoxelBox* const mbox = &moving_box;  // the caller's, from SplitPair
  // Images of the moving voxels, kept for the neighbour checks below.
  const FeatureField image_index{*mbox, {}};
  if (jump > 0) {
    // Only moving voxels' entries are written and read: no fill, no copy.
    if (images.capacity() < size_t(mbox->Volume())) images.clear();
    images.resize(size_t(mbox->Volume()));
  }
  std::atomic<bool> cancelled{false};
  std::atomic<uint64_t> done{0};
  const uint64_t work = uint64_t(res.z) * (jump > 0 ? 2 : 1);
  const tbb::blocked_range<int> slabs(mbox->min.z, mbox->max.z + 1, 2);
  auto poll = [&](uint64_t units) {
    if (intr.WasInterrupted(done.fetch_add(units) + units, work)) cancelled = true;
  };
  tbb::parallel_for(slabs, [&](const tbb::blocked_range<int>& r) {
    if (cancelled) return;
    moving.ForEachInSlabs(r.begin(), r.end(), [&](int x, int y, int z) {
      const PackedVoxel pf = field.At(x, y, z);
      // An empty target leaves nothing to move toward: keep the voxel.
      const Int3 m =
          pf == kNoVoxel ? Int3{x, y, z} : Midpoint({x, y, z}, UnpackVoxel(pf), round_up);
      SetAtomic(out, m.x, m.y, m.z);
      if (jump > 0) images[image_index.Index(x, y, z)] = PackVoxel(m);
    });
    poll(r.size());
  });
  if (cancelled) return absl::CancelledError("median interrupted");
  if (jump <= 0) return absl::OkStatus();

  // Image and nearest point of a source voxel; target members stay put.
  auto lookup = [&](Int3 v, Int3& f) {
    if (!moving.Get(v)) {
      f = v;
      return v;
    }
    f = UnpackVoxel(field.At(v));
    return UnpackVoxel(images[image_index.Index(v.x, v.y, v.z)]);
  };
  // Fills the image of the cube a + {0,1}^3 when it lies wholly in the
  // source and the nearest-point map is continuous over it.
  auto fill_cube = [&](Int3 a) {
    Int3 corner[8], corner_img[8], corner_f[8];
    Int3 flo{1 << 30, 1 << 30, 1 << 30}, fhi{-1, -1, -1};
    for (int c = 0; c < 8; ++c) {
      corner[c] = Add(a, {c & 1, (c >> 1) & 1, (c >> 2) & 1});
      if (!source.Contains(corner[c])) return;
      corner_img[c] = lookup(corner[c], corner_f[c]);
      flo = {std::min(flo.x, corner_f[c].x), std::min(flo.y, corner_f[c].y),
             std::min(flo.z, corner_f[c].z)};
      fhi = {std::max(fhi.x, corner_f[c].x), std::max(fhi.y, corner_f[c].y),
             std::max(fhi.z, corner_f[c].z)};
    }
    if (Chebyshev(flo, fhi) > jump) return;
    for (int i = 0; i < 8; ++i)
      for (int j = i + 1; j < 8; ++j)
        if (!Coherent(corner[i], corner_f[i], corner[j], corner_f[j])) return;
    // Six tetrahedra around the diagonal 0-7 tile the cube.
    static constexpr int kTets[6][4] = {{0, 1, 3, 7}, {0, 1, 5, 7}, {0, 2, 3, 7},
                                        {0, 2, 6, 7}, {0, 4, 5, 7}, {0, 4, 6, 7}};
    for (const auto& t : kTets) {
      const Int3 p[4] = {corner_img[t[0]], corner_img[t[1]], corner_img[t[2]], corner_img[t[3]]};
      FillTetrahedron(p, out);
    }
  };
  // Rows of the source, the moving set and the images around one row; the
  // neighbour tests below are bit tests on these (null outside the lattice
  // or, for images, outside the moving box, where nothing moves).
  struct Rows {
    const uint64_t* src = nullptr;
    const uint64_t* mov = nullptr;
    const PackedVoxel* img = nullptr;
  };
  auto rows_at = [&](int y, int z) {
    Rows r;
    if (y < 0 || z < 0 || y >= res.y || z >= res.z) return r;
    r.src = source.Row(y, z);
    r.mov = moving.Row(y, z);
    if (y >= mbox->min.y && y <= mbox->max.y && z >= mbox->min.z && z <= mbox->max.z)
      r.img = images.data() + image_index.Index(mbox->min.x, y, z) - size_t(mbox->min.x);
    return r;
  };
  auto bit = [](const uint64_t* row, int x) { return (row[x >> 6] >> (x & 63)) & 1; };
  tbb::parallel_for(slabs, [&](const tbb::blocked_range<int>& r) {
    if (cancelled) return;
    for (int z = r.begin(); z < r.end(); ++z) {
      for (int y = mbox->min.y; y <= mbox->max.y; ++y) {
        const Rows here = rows_at(y, z);
        bool any = false;
        for (int w = mbox->min.x >> 6; w <= mbox->max.x >> 6 && !any; ++w) any = here.mov[w];
        if (!any) continue;
        // Neighbours in -x, +x, -y, +y, -z, +z order.
        const Rows around[6] = {
            here, here, rows_at(y - 1, z), rows_at(y + 1, z), rows_at(y, z - 1), rows_at(y, z + 1)};
        static constexpr int kStep[6][3] = {{-1, 0, 0}, {1, 0, 0},  {0, -1, 0},
                                            {0, 1, 0},  {0, 0, -1}, {0, 0, 1}};
        for (int w = mbox->min.x >> 6; w <= mbox->max.x >> 6; ++w) {
          for (uint64_t bits = here.mov[w]; bits; bits &= bits - 1) {
            const int x = (w << 6) + std::countr_zero(bits);
            const Int3 a{x, y, z};
            const Int3 m = UnpackVoxel(here.img[x]);
            Int3 f{-1, -1, -1};  // fetched only when a gap shows up
            bool stretched = false;
            for (int k = 0; k < 6; ++k) {
              const Rows& nr = around[k];
              const int nx = x + kStep[k][0];
              if (!nr.src || nx < 0 || nx >= res.x || !bit(nr.src, nx)) continue;
              const bool n_moving = bit(nr.mov, nx);
              if ((k & 1) == 0 && n_moving) continue;  // that pair is handled from n
              const Int3 n{nx, y + kStep[k][1], z + kStep[k][2]};
              const Int3 mn = n_moving ? UnpackVoxel(nr.img[nx]) : n;
              const int gap = Chebyshev(m, mn);
              if (gap < 2) continue;
              if (f.x < 0) f = UnpackVoxel(field.At(a));
              const Int3 fn = n_moving ? UnpackVoxel(field.At(n)) : n;
              if (Chebyshev(f, fn) > jump || !Coherent(a, f, n, fn)) continue;
              if (k & 1) stretched = true;
              for (int s = 1; s < gap; ++s) {
                const double t = double(s) / gap;
                SetAtomic(out, m.x + int(std::lround((mn.x - m.x) * t)),
                          m.y + int(std::lround((mn.y - m.y) * t)),
                          m.z + int(std::lround((mn.z - m.z) * t)));
              }
            }
            if (stretched) fill_cube(a);
          }
        }
      }
    }
    poll(r.size());
  });
  if (cancelled) return absl::CancelledError("median interrupted");
  return absl::OkStatus();
}

// ws.field = `target`'s feature transform, computed only over the box the
// voxels of `moving` need and queried there; timed as nearest-point work.
absl::Status NearestFieldFor(const VoxelSet& target, const VoxelSet& moving,
                             const VoxelBox& moving_box, Vec3 h, SetMapWorkspace& ws) {
  const auto t0 = Clock::now();
  FeatureTransformOptions fo;
  fo.box = moving_box;
  fo.queries = &moving;
  NIMBUS_RETURN_IF_ERROR(ComputeFeatureTransform(target, h, fo, ws.field, ws.interrupter));
  ws.stats.nearest_seconds += SecondsSince(t0);
  return absl::OkStatus();
}

// Bounding box of the members of the rows added so far (rows of one slab,
// then slab boxes merged); `any` is false while no member has been seen.
struct BoxAccumulator {
  bool any = false;
  VoxelBox box{{0, 0, 0}, {0, 0, 0}};
  void AddRow(const uint64_t* row, int words, int y, int z) {
    int first = 0;
    while (first < words && !row[first]) ++first;
    if (first == words) return;
    int last = words - 1;
    while (!row[last]) --last;
    const int x0 = (first << 6) + std::countr_zero(row[first]);
    const int x1 = (last << 6) + 63 - std::countl_zero(row[last]);
    Add({{x0, y, z}, {x1, y, z}});
  }
  void Add(const VoxelBox& b) {
    box = any ? VoxelBox::Hull(box, b) : b;
    any = true;
  }
  std::optional<VoxelBox> Get() const { return any ? std::optional<VoxelBox>(box) : std::nullopt; }
};

// The one pass of set algebra a median needs: out = a ∩ b, moving_a =
// a \ b and (when `both_sides`) moving_b = b \ a, with the bounding boxes of
// the two differences. Buffers are reused; slabs of slices run in parallel.
struct SplitBoxes {
  std::optional<VoxelBox> a, b;
};
SplitBoxes SplitPair(const VoxelSet& a, const VoxelSet& b, bool both_sides, VoxelSet& out,
                     VoxelSet& moving_a, VoxelSet& moving_b) {
  const Int3 res = a.resolution();
  for (VoxelSet* s : {&out, &moving_a, &moving_b})
    if (!(s->resolution() == res) || s->words().size() != a.words().size()) *s = VoxelSet(res);
  const int words = a.words_per_row();
  constexpr int kSlab = 8;
  const int slabs = (res.z + kSlab - 1) / kSlab;
  std::vector<BoxAccumulator> box_a(static_cast<size_t>(slabs)), box_b(box_a);
  tbb::parallel_for(tbb::blocked_range<int>(0, slabs), [&](const tbb::blocked_range<int>& r) {
    for (int sl = r.begin(); sl < r.end(); ++sl)
      for (int z = sl * kSlab; z < std::min(res.z, (sl + 1) * kSlab); ++z)
        for (int y = 0; y < res.y; ++y) {
          const uint64_t* ra = a.Row(y, z);
          const uint64_t* rb = b.Row(y, z);
          uint64_t* o = out.MutableRow(y, z);
          uint64_t* ma = moving_a.MutableRow(y, z);
          uint64_t* mb = moving_b.MutableRow(y, z);
          for (int w = 0; w < words; ++w) {
            o[w] = ra[w] & rb[w];
            ma[w] = ra[w] & ~rb[w];
          }
          box_a[size_t(sl)].AddRow(ma, words, y, z);
          if (!both_sides) continue;
          for (int w = 0; w < words; ++w) mb[w] = rb[w] & ~ra[w];
          box_b[size_t(sl)].AddRow(mb, words, y, z);
        }
  });
  BoxAccumulator all_a, all_b;
  for (int sl = 0; sl < slabs; ++sl) {
    if (box_a[size_t(sl)].any) all_a.Add(box_a[size_t(sl)].box);
    if (box_b[size_t(sl)].any) all_b.Add(box_b[size_t(sl)].box);
  }
  return {all_a.Get(), all_b.Get()};
}

// out = D_a(b) (left only) or M(a, b). `b_field`, when given, is b's
// feature transform over the whole lattice; otherwise the needed parts of
// both transforms are computed into ws.field. A voxel moves only when it
// is outside the other set, so the transforms are queried at a - b and
// b - a only, and computed over the box those need.
absl::Status MedianInto(const VoxelSet& a, const VoxelSet& b, const FeatureField* b_field,
                        const Vec3 h, const MedianOptions& options, bool both_sides,
                        SetMapWorkspace& ws, VoxelSet& out) {
  Interrupter& intr = OrNull(ws.interrupter);
  const uint64_t seed = options.seed ^ ws.seed;
  const SplitBoxes boxes = SplitPair(a, b, both_sides, out, ws.moving_a, ws.moving_b);
  if (boxes.a) {
    const FeatureField* field = b_field;
    if (!field) {
      NIMBUS_RETURN_IF_ERROR(NearestFieldFor(b, ws.moving_a, *boxes.a, h, ws));
      field = &ws.field;
    }
    NIMBUS_RETURN_IF_ERROR(
        AddMidpoints(ws.moving_a, a, *field, options, seed, *boxes.a, ws.images, out, intr));
  }
  if (!both_sides) return absl::OkStatus();
  if (boxes.b) {
    NIMBUS_RETURN_IF_ERROR(NearestFieldFor(a, ws.moving_b, *boxes.b, h, ws));
    NIMBUS_RETURN_IF_ERROR(
        AddMidpoints(ws.moving_b, b, ws.field, options, seed, *boxes.b, ws.images, out, intr));
  }
  return absl::OkStatus();
}

// ---------------------------------------------------------------- affine images

// Index space: voxel i spans [i, i + 1). World p = min + h * u.
Affine3 WorldToIndexSpace(const Affine3& world, const GridFrame& frame) {
  const Vec3 h = frame.VoxelSize();
  const Vec3 m = frame.bounds.min;
  const Affine3 to_world = Affine3::Translate(m) * Affine3::Scale(h);
  const Affine3 to_index =
      Affine3::Scale({1 / h.x, 1 / h.y, 1 / h.z}) * Affine3::Translate(-1.0 * m);
  return to_index * world * to_world;
}

std::optional<Affine3> Inverse(const Affine3& f) {
  const auto& m = f.m;
  const double det = f.Determinant();
  if (!(std::abs(det) > 1e-12)) return std::nullopt;
  Affine3 inv;
  auto& r = inv.m;
  r[0][0] = (m[1][1] * m[2][2] - m[1][2] * m[2][1]) / det;
  r[0][1] = (m[0][2] * m[2][1] - m[0][1] * m[2][2]) / det;
  r[0][2] = (m[0][1] * m[1][2] - m[0][2] * m[1][1]) / det;
  r[1][0] = (m[1][2] * m[2][0] - m[1][0] * m[2][2]) / det;
  r[1][1] = (m[0][0] * m[2][2] - m[0][2] * m[2][0]) / det;
  r[1][2] = (m[0][2] * m[1][0] - m[0][0] * m[1][2]) / det;
  r[2][0] = (m[1][0] * m[2][1] - m[1][1] * m[2][0]) / det;
  r[2][1] = (m[0][1] * m[2][0] - m[0][0] * m[2][1]) / det;
  r[2][2] = (m[0][0] * m[1][1] - m[0][1] * m[1][0]) / det;
  const Vec3 t = inv.ApplyLinear(f.translation());
  r[0][3] = -t.x;
  r[1][3] = -t.y;
  r[2][3] = -t.z;
  return inv;
}

// Image of `in` under an index-space affine map, written to `out`.
void TransformIndexSpace(const VoxelSet& in, const Affine3& g, VoxelSet& out) {
  const Int3 res = in.resolution();
  out = VoxelSet(res);
  const std::optional<VoxelBox> box = in.BoundingBox();
  if (!box) return;
  const std::optional<Affine3> inv = Inverse(g);
  if (inv) {
    // Pull: the image box from the eight corners of the source box.
    Vec3 lo{1e300, 1e300, 1e300}, hi{-1e300, -1e300, -1e300};
    for (int c = 0; c < 8; ++c) {
      const Vec3 p = g.Apply({double(c & 1 ? box->max.x + 1 : box->min.x),
                              double(c & 2 ? box->max.y + 1 : box->min.y),
                              double(c & 4 ? box->max.z + 1 : box->min.z)});
      for (int a = 0; a < 3; ++a) {
        lo[a] = std::min(lo[a], p[a]);
        hi[a] = std::max(hi[a], p[a]);
      }
    }
    int b0[3], b1[3];
    for (int a = 0; a < 3; ++a) {
      b0[a] = int(std::max(0.0, std::floor(lo[a])));
      b1[a] = int(std::min(double(res[a] - 1), std::floor(hi[a])));
    }
    if (b0[0] <= b1[0] && b0[1] <= b1[1] && b0[2] <= b1[2]) {
      const Vec3 step{inv->m[0][0], inv->m[1][0], inv->m[2][0]};
      // Rows are split by z across threads and each thread owns its rows.
      const tbb::blocked_range<int> slabs(b0[2], b1[2] + 1, 2);
      tbb::parallel_for(slabs, [&](const tbb::blocked_range<int>& r) {
        for (int z = r.begin(); z < r.end(); ++z)
          for (int y = b0[1]; y <= b1[1]; ++y) {
            Vec3 p = inv->Apply({b0[0] + 0.5, y + 0.5, z + 0.5});
            for (int x = b0[0]; x <= b1[0]; ++x, p = p + step) {
              const int sx = int(std::floor(p.x)), sy = int(std::floor(p.y)),
                        sz = int(std::floor(p.z));
              if (in.InBounds(sx, sy, sz) && in.Get(sx, sy, sz)) out.Set(x, y, z);
            }
          }
      });
    }
  }
  if (!inv || g.SmallestSingularValue() < 1 - 1e-9) {
    tbb::parallel_for(tbb::blocked_range<int>(0, res.z, 2), [&](const tbb::blocked_range<int>& r) {
      in.ForEachInSlabs(r.begin(), r.end(), [&](int x, int y, int z) {
        const Vec3 p = g.Apply({x + 0.5, y + 0.5, z + 0.5});
        const int tx = int(std::floor(p.x)), ty = int(std::floor(p.y)), tz = int(std::floor(p.z));
        if (out.InBounds(tx, ty, tz)) SetAtomic(out, tx, ty, tz);
      });
    });
  }
}

// ---------------------------------------------------------------- rotated median

Vec3 BoxCentre(const VoxelBox& b) {  // index space
  return {0.5 * (b.min.x + b.max.x + 1), 0.5 * (b.min.y + b.max.y + 1),
          0.5 * (b.min.z + b.max.z + 1)};
}

Int3 RoundVec(Vec3 v) {
  return {int(std::lround(v.x)), int(std::lround(v.y)), int(std::lround(v.z))};
}

// out = M~(a, b); `b_field` as in MedianInto.
absl::Status RotatedMedianInto(const VoxelSet& a, const VoxelSet& b, const FeatureField* b_field,
                               const GridFrame& frame, const RotatedMedianOptions& options,
                               SetMapWorkspace& ws, VoxelSet& out) {
  const Vec3 h = frame.VoxelSize();
  const Vec3 ca = BoxCentre(*a.BoundingBox()), cb = BoxCentre(*b.BoundingBox());
  const Vec3 mid = 0.5 * (ca + cb);
  const Vec3 gap = ca - cb;
  const double distance = Length({gap.x * h.x, gap.y * h.y, gap.z * h.z});
  const double degrees = options.degrees_per_unit * distance;
  Int3 shift_b{0, 0, 0};
  ws.staged = VoxelSet(a.resolution());
  if (options.superpose) {
    // Move a onto b's centre, take the median there (b's transform stays
    // valid), then carry the result to the midpoint: whole voxels only.
    const Int3 ta = RoundVec(mid - ca);
    shift_b = RoundVec(mid - cb);
    ws.shifted = ShiftSet(a, {ta.x - shift_b.x, ta.y - shift_b.y, ta.z - shift_b.z});
    if (ws.shifted.Empty()) ws.shifted = a;  // shifted off the lattice: fall back
    NIMBUS_RETURN_IF_ERROR(
        MedianInto(ws.shifted, b, b_field, h, options.median, true, ws, ws.staged));
  } else {
    NIMBUS_RETURN_IF_ERROR(MedianInto(a, b, b_field, h, options.median, true, ws, ws.staged));
  }
  if (std::abs(degrees) < 1e-9) {
    out = shift_b == Int3{0, 0, 0} ? ws.staged : ShiftSet(ws.staged, shift_b);
    return absl::OkStatus();
  }
  const Vec3 pivot = frame.bounds.min + Vec3{mid.x * h.x, mid.y * h.y, mid.z * h.z};
  const Affine3 world = Affine3::Translate(pivot) * Affine3::Rotate(options.axis, degrees) *
                        Affine3::Translate(-1.0 * pivot) *
                        Affine3::Translate({shift_b.x * h.x, shift_b.y * h.y, shift_b.z * h.z});
  TransformIndexSpace(ws.staged, WorldToIndexSpace(world, frame), out);
  return absl::OkStatus();
}

// ---------------------------------------------------------------- maps

// Shared parts of the maps that condense toward a fixed set C: an empty
// input maps to C itself, and every application is timed and counted.
class CondensingMap : public SetMap {
 public:
  absl::Status Apply(const VoxelSet& in, VoxelSet& out, SetMapWorkspace& ws) const final {
    const auto t0 = Clock::now();
    absl::Status s;
    if (in.Empty())
      out = condensation();
    else
      s = Condense(in, out, ws);
    ws.stats.seconds += SecondsSince(t0);
    ++ws.stats.applications;
    return s;
  }

 protected:
  CondensingMap(const GridFrame& frame, VoxelSet c, FeatureField field)
      : SetMap(frame), c_(std::move(c)), field_(std::move(field)) {}
  const VoxelSet& condensation() const { return c_; }
  const FeatureField& field() const { return field_; }
  // The map on a non-empty input.
  virtual absl::Status Condense(const VoxelSet& in, VoxelSet& out, SetMapWorkspace& ws) const = 0;

 private:
  VoxelSet c_;
  FeatureField field_;  // C's nearest voxel for every lattice voxel
};

class MedianMap final : public CondensingMap {
 public:
  MedianMap(const GridFrame& frame, VoxelSet c, FeatureField field, MedianOptions options)
      : CondensingMap(frame, std::move(c), std::move(field)), options_(options) {}
  SetMapKind kind() const override { return SetMapKind::kMedian; }
  std::string Describe() const override {
    return absl::StrCat("median toward a set of ", condensation().Count(), " voxels");
  }

 private:
  absl::Status Condense(const VoxelSet& in, VoxelSet& out, SetMapWorkspace& ws) const override {
    return MedianInto(in, condensation(), &field(), frame().VoxelSize(), options_, true, ws, out);
  }
  MedianOptions options_;
};

class RotatedMedianMap final : public CondensingMap {
 public:
  RotatedMedianMap(const GridFrame& frame, VoxelSet c, FeatureField field,
                   RotatedMedianOptions options)
      : CondensingMap(frame, std::move(c), std::move(field)), options_(options) {}
  SetMapKind kind() const override { return SetMapKind::kRotatedMedian; }
  std::string Describe() const override {
    return absl::StrCat("rotated median (", options_.degrees_per_unit,
                        " deg/unit) toward a set of ", condensation().Count(), " voxels");
  }

 private:
  absl::Status Condense(const VoxelSet& in, VoxelSet& out, SetMapWorkspace& ws) const override {
    return RotatedMedianInto(in, condensation(), &field(), frame(), options_, ws, out);
  }
  RotatedMedianOptions options_;
};

class ConstantMap final : public SetMap {
 public:
  ConstantMap(const GridFrame& frame, VoxelSet c) : SetMap(frame), c_(std::move(c)) {}
  SetMapKind kind() const override { return SetMapKind::kConstant; }
  std::string Describe() const override {
    return absl::StrCat("constant condensation, ", c_.Count(), " voxels");
  }
  absl::Status Apply(const VoxelSet&, VoxelSet& out, SetMapWorkspace& ws) const override {
    out = c_;
    ++ws.stats.applications;
    return absl::OkStatus();
  }

 private:
  VoxelSet c_;
};

class PointSetMap final : public SetMap {
 public:
  PointSetMap(const GridFrame& frame, PointMap map, PointSetMapOptions options)
      : SetMap(frame), map_(std::move(map)), options_(options) {}
  SetMapKind kind() const override { return SetMapKind::kPoint; }
  std::string Describe() const override {
    return absl::StrCat("point map '", map_.name, "'", map_.IsAffine() ? " (affine)" : "");
  }
  absl::Status Apply(const VoxelSet& in, VoxelSet& out, SetMapWorkspace& ws) const override {
    const auto t0 = Clock::now();
    if (map_.IsAffine()) {
      TransformIndexSpace(in, WorldToIndexSpace(map_.pre, frame()), out);
    } else {
      PushForward(in, out, ws.seed);
    }
    ws.stats.seconds += SecondsSince(t0);
    ++ws.stats.applications;
    if (OrNull(ws.interrupter).WasInterrupted())
      return absl::CancelledError("point map interrupted");
    return absl::OkStatus();
  }

 private:
  // Nonlinear maps have no inverse to pull through: push voxel samples
  // forward, as many per voxel as the local stretch asks for.
  void PushForward(const VoxelSet& in, VoxelSet& out, uint64_t seed) const {
    const GridFrame& f = frame();
    const Vec3 h = f.VoxelSize();
    const Int3 res = in.resolution();
    out = VoxelSet(res);
    auto to_index = [&](Vec3 w) {
      return Vec3{(w.x - f.bounds.min.x) / h.x, (w.y - f.bounds.min.y) / h.y,
                  (w.z - f.bounds.min.z) / h.z};
    };
    auto plot = [&](Vec3 w) {
      const Vec3 u = to_index(w);
      if (!(std::isfinite(u.x) && std::isfinite(u.y) && std::isfinite(u.z))) return;
      const double x = std::floor(u.x), y = std::floor(u.y), z = std::floor(u.z);
      if (x < 0 || y < 0 || z < 0 || x >= res.x || y >= res.y || z >= res.z) return;
      SetAtomic(out, int(x), int(y), int(z));
    };
    const int max_n = std::max(1, options_.max_subdivision);
    tbb::parallel_for(tbb::blocked_range<int>(0, res.z, 1), [&](const tbb::blocked_range<int>& r) {
      for (int z = r.begin(); z < r.end(); ++z) {
        // One stream per slice: results do not depend on thread scheduling.
        Rng rng(seed, uint64_t(z));
        in.ForEachInSlabs(z, z + 1, [&](int x, int y, int zz) {
          const Vec3 c = f.VoxelCenter({x, y, zz});
          const Vec3 w0 = map_.Apply(c, rng);
          const Vec3 q = to_index(w0);
          double stretch = 0;
          for (int a = 0; a < 3; ++a) {
            Vec3 d{};
            d[a] = 0.5 * h[a];
            const Vec3 q1 = to_index(map_.Apply(c + d, rng));
            for (int k = 0; k < 3; ++k) stretch = std::max(stretch, 2 * std::abs(q1[k] - q[k]));
          }
          int n = std::isfinite(stretch) ? int(std::ceil(2 * stretch)) : max_n;
          n = std::clamp(n, 1, max_n);
          if (n == 1) {
            plot(w0);
            return;
          }
          for (int i = 0; i < n; ++i)
            for (int j = 0; j < n; ++j)
              for (int k = 0; k < n; ++k) {
                const Vec3 s{c.x + h.x * ((i + 0.5) / n - 0.5), c.y + h.y * ((j + 0.5) / n - 0.5),
                             c.z + h.z * ((k + 0.5) / n - 0.5)};
                plot(map_.Apply(s, rng));
              }
        });
      }
    });
  }

  PointMap map_;
  PointSetMapOptions options_;
};

absl::StatusOr<FeatureField> PrepareCondensation(const GridFrame& frame, const VoxelSet& c,
                                                 Interrupter* interrupter) {
  NIMBUS_RETURN_IF_ERROR(ValidateSetFrame(frame));
  if (!(c.resolution() == frame.resolution))
    return absl::InvalidArgumentError("condensation set resolution differs from the grid frame");
  if (c.Empty()) return absl::InvalidArgumentError("condensation set is empty");
  return ComputeFeatureTransform(c, frame.VoxelSize(), interrupter);
}

}  // namespace

namespace {
// The one-shot median of two checked sets, with a workspace of its own.
absl::StatusOr<VoxelSet> MedianOnce(const VoxelSet& a, const VoxelSet& b, const GridFrame& frame,
                                    const MedianOptions& options, bool symmetric,
                                    Interrupter* interrupter) {
  SetMapWorkspace ws;
  ws.interrupter = interrupter;
  VoxelSet out;
  NIMBUS_RETURN_IF_ERROR(MedianInto(a, b, nullptr, frame.VoxelSize(), options, symmetric, ws, out));
  return out;
}
}  // namespace

absl::StatusOr<VoxelSet> LeftMedian(const VoxelSet& a, const VoxelSet& b, const GridFrame& frame,
                                    const MedianOptions& options, Interrupter* interrupter) {
  NIMBUS_RETURN_IF_ERROR(CheckPair(a, b, frame));
  if (b.Empty()) return absl::InvalidArgumentError("left median: the target set is empty");
  return MedianOnce(a, b, frame, options, false, interrupter);
}

absl::StatusOr<VoxelSet> Median(const VoxelSet& a, const VoxelSet& b, const GridFrame& frame,
                                const MedianOptions& options, Interrupter* interrupter) {
  NIMBUS_RETURN_IF_ERROR(CheckPair(a, b, frame));
  if (a.Empty() || b.Empty()) return absl::InvalidArgumentError("median: a set is empty");
  return MedianOnce(a, b, frame, options, true, interrupter);
}

absl::StatusOr<VoxelSet> RotatedMedian(const VoxelSet& a, const VoxelSet& b, const GridFrame& frame,
                                       const RotatedMedianOptions& options,
                                       Interrupter* interrupter) {
  NIMBUS_RETURN_IF_ERROR(CheckPair(a, b, frame));
  if (a.Empty() || b.Empty()) return absl::InvalidArgumentError("rotated median: a set is empty");
  if (!IsFinite(options.axis) || !(Length(options.axis) > 0) ||
      !std::isfinite(options.degrees_per_unit))
    return absl::InvalidArgumentError("rotated median: axis must be non-zero, angle finite");
  SetMapWorkspace ws;
  ws.interrupter = interrupter;
  VoxelSet out;
  NIMBUS_RETURN_IF_ERROR(RotatedMedianInto(a, b, nullptr, frame, options, ws, out));
  return out;
}

VoxelSet TransformSet(const VoxelSet& set, const GridFrame& frame, const Affine3& world_map) {
  VoxelSet out;
  TransformIndexSpace(set, WorldToIndexSpace(world_map, frame), out);
  return out;
}

absl::StatusOr<SetMapPtr> MakeMedianMap(const GridFrame& frame, VoxelSet condensation,
                                        const MedianOptions& options, Interrupter* interrupter) {
  NIMBUS_ASSIGN_OR_RETURN(FeatureField field,
                          PrepareCondensation(frame, condensation, interrupter));
  return std::make_shared<MedianMap>(frame, std::move(condensation), std::move(field), options);
}

absl::StatusOr<SetMapPtr> MakeRotatedMedianMap(const GridFrame& frame, VoxelSet condensation,
                                               const RotatedMedianOptions& options,
                                               Interrupter* interrupter) {
  if (!IsFinite(options.axis) || !(Length(options.axis) > 0) ||
      !std::isfinite(options.degrees_per_unit))
    return absl::InvalidArgumentError("rotated median: axis must be non-zero, angle finite");
  NIMBUS_ASSIGN_OR_RETURN(FeatureField field,
                          PrepareCondensation(frame, condensation, interrupter));
  return std::make_shared<RotatedMedianMap>(frame, std::move(condensation), std::move(field),
                                            options);
}

absl::StatusOr<SetMapPtr> MakeConstantMap(const GridFrame& frame, VoxelSet condensation) {
  NIMBUS_RETURN_IF_ERROR(ValidateSetFrame(frame));
  if (!(condensation.resolution() == frame.resolution))
    return absl::InvalidArgumentError("condensation set resolution differs from the grid frame");
  if (condensation.Empty()) return absl::InvalidArgumentError("condensation set is empty");
  return std::make_shared<ConstantMap>(frame, std::move(condensation));
}

absl::StatusOr<SetMapPtr> MakePointSetMap(const GridFrame& frame, PointMap map,
                                          const PointSetMapOptions& options) {
  NIMBUS_RETURN_IF_ERROR(ValidateSetFrame(frame));
  if (options.max_subdivision < 1 || options.max_subdivision > 16)
    return absl::InvalidArgumentError("point set map: max_subdivision must be in 1..16");
  return std::make_shared<PointSetMap>(frame, std::move(map), options);
}

}  // namespace nimbus
