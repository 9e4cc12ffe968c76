#include "core/sets/set_maps.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_invoke.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <optional>
#include <vector>

#include "absl/strings/str_cat.h"
#include "core/base/random.h"
#include "core/base/status_macros.h"
#include "core/sets/cube_image.h"
#include "core/sets/gap_pretest.h"

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

// std::lround for |v| < 2^31, inline (the portable build calls libm for
// it): truncation, then the fraction v - trunc(v), which is exact, decides.
inline int RoundHalfAway(double v) {
  const int64_t i = int64_t(v);
  const double f = v - double(i);
  return int(i + (f >= 0.5) - (f <= -0.5));
}

inline int Chebyshev(Int3 a, Int3 b) {
  return std::max({std::abs(a.x - b.x), std::abs(a.y - b.y), std::abs(a.z - b.z)});
}


// A voxel's motion toward its nearest point, with its squared length.
struct Motion {
  int64_t x, y, z, len2;
};
inline Motion MotionOf(Int3 a, Int3 fa) {
  const int64_t x = fa.x - a.x, y = fa.y - a.y, z = fa.z - a.z;
  return {x, y, z, x * x + y * y + z * z};
}

// True when the nearest-point map looks continuous between nearby source
// voxels a and n = a + d, which move by u and v. Two moving voxels must
// move in directions at most 60 degrees apart: across a medial axis of the
// target they move apart, a tear the exact image has too. A voxel that does
// not move (it is in the target) agrees with a moving one unless that one
// moves away from it, which again means a medial axis runs between them.
inline bool Coherent(const Motion& u, const Motion& v, Int3 d) {
  if (u.len2 == 0 && v.len2 == 0) return true;
  if (v.len2 == 0) return u.x * d.x + u.y * d.y + u.z * d.z >= 0;
  if (u.len2 == 0) return v.x * -d.x + v.y * -d.y + v.z * -d.z >= 0;
  const int64_t dot = u.x * v.x + u.y * v.y + u.z * v.z;
  return dot > 0 && 4 * dot * dot >= u.len2 * v.len2;
}
inline bool Coherent(Int3 a, Int3 fa, Int3 n, Int3 fn) {
  return Coherent(MotionOf(a, fa), MotionOf(n, fn), {n.x - a.x, n.y - a.y, n.z - a.z});
}

// The 28 pairs of a cube's corners (i < j, in that order) with the step
// from corner i to corner j: a table, so the coherence tests of a cube do
// not recompute them.
struct CornerPair {
  int i, j;
  Int3 d;
};
constexpr std::array<CornerPair, 28> kCornerPairs = [] {
  std::array<CornerPair, 28> pairs{};
  int n = 0;
  for (int i = 0; i < 8; ++i)
    for (int j = i + 1; j < 8; ++j)
      pairs[n++] = {
          i, j, {(j & 1) - (i & 1), ((j >> 1) & 1) - ((i >> 1) & 1), (j >> 2) - (i >> 2)}};
  return pairs;
}();

absl::Status CheckPair(const VoxelSet& a, const VoxelSet& b, const GridFrame& frame) {
  NIMBUS_RETURN_IF_ERROR(ValidateSetFrame(frame));
  if (!(a.resolution() == frame.resolution) || !(b.resolution() == frame.resolution))
    return absl::InvalidArgumentError("set map: set resolution differs from the grid frame");
  return absl::OkStatus();
}

// Members of a word. The portable build has no popcnt instruction, and
// std::popcount then calls a library routine; this inlines the same count.
inline uint32_t PopCount(uint64_t v) {
  v = v - ((v >> 1) & 0x5555555555555555ULL);
  v = (v & 0x3333333333333333ULL) + ((v >> 2) & 0x3333333333333333ULL);
  v = (v + (v >> 4)) & 0x0f0f0f0f0f0f0f0fULL;
  return uint32_t((v * 0x0101010101010101ULL) >> 56);
}

// Numbers the members of a set inside a box in row order (x fastest), so
// that per-member data can live in compact arrays instead of box-sized
// ones: the moving voxels are a few percent of their box, and a box-sized
// array (or a lattice-sized field) read at them misses the cache on almost
// every access. A member's rank is the rank of the first member of its
// 64-bit word plus the members before it in that word.
struct MemberRanks {
  VoxelBox box;
  int w0 = 0, nw = 0, ny = 0;
  const uint32_t* first = nullptr;  // per (row, word) of the box

  // Index of word w0 of row (y, z) in `first`.
  size_t Slot(int y, int z) const {
    return (size_t(z - box.min.z) * size_t(ny) + size_t(y - box.min.y)) * size_t(nw);
  }
};

// Ranks the members of `set` inside `box` into `first` (reused); returns
// the member count. A prefix sum in three steps, so that only one entry per
// slice is summed serially: each slice's words are counted and summed in
// parallel, then the slices' totals in order, then each slice adds the
// members of the slices before it, in parallel again.
uint32_t RankMembers(const VoxelSet& set, const VoxelBox& box, std::vector<uint32_t>& first,
                     MemberRanks& ranks) {
  ranks.box = box;
  ranks.w0 = box.min.x >> 6;
  ranks.nw = (box.max.x >> 6) - ranks.w0 + 1;
  ranks.ny = box.Size().y;
  const size_t per_slice = size_t(ranks.ny) * size_t(ranks.nw);
  first.resize(per_slice * size_t(box.Size().z));
  std::vector<uint32_t> before(size_t(box.Size().z));  // members of the slice, then of those below
  const tbb::blocked_range<int> slices(box.min.z, box.max.z + 1, 8);
  tbb::parallel_for(slices, [&](const tbb::blocked_range<int>& r) {
    for (int z = r.begin(); z < r.end(); ++z) {
      uint32_t total = 0;
      uint32_t* f = first.data() + ranks.Slot(box.min.y, z);
      for (int y = box.min.y; y <= box.max.y; ++y) {
        const uint64_t* row = set.Row(y, z) + ranks.w0;
        for (int w = 0; w < ranks.nw; ++w, ++f) {
          *f = total;
          total += PopCount(row[w]);
        }
      }
      before[size_t(z - box.min.z)] = total;
    }
  });
  uint32_t total = 0;
  for (uint32_t& n : before) {
    const uint32_t in_slice = n;
    n = total;
    total += in_slice;
  }
  tbb::parallel_for(slices, [&](const tbb::blocked_range<int>& r) {
    for (int z = r.begin(); z < r.end(); ++z) {
      const uint32_t add = before[size_t(z - box.min.z)];
      if (add == 0) continue;
      uint32_t* f = first.data() + ranks.Slot(box.min.y, z);
      for (size_t i = 0; i < per_slice; ++i) f[i] += add;
    }
  });
  ranks.first = first.data();
  return total;
}

// @brief One AddMidpoints call (below): the moving voxels' images, then
// the gap filling between neighbours.
class MidpointPass {
 public:
  MidpointPass(const VoxelSet& moving, const VoxelSet& source, const FeatureField& field,
               const MedianOptions& options, uint64_t seed, const VoxelBox& moving_box,
               MovingBuffers& ws, VoxelSet& out, Interrupter& intr)
      : moving(moving),
        source(source),
        field(field),
        out(out),
        intr(intr),
        res(moving.resolution()),
        round_up(unsigned(Mix64(seed) >> 61)),
        jump(options.bridge_max_jump),
        mbox(&moving_box),  // the caller's, from SplitPair
        count(RankMembers(moving, *mbox, ws.rank_first, ranks)),
        images(ws.images),
        nearest(ws.nearest),
        work(uint64_t(res.z) * (jump > 0 ? 2 : 1)),
        slabs(mbox->min.z, mbox->max.z + 1, 2) {}

  absl::Status Run() {
    // Images and nearest points of the moving voxels, by rank; every entry
    // is written by the first loop, so the buffers skip the fill.
    if (jump > 0) {
      if (images.capacity() < count) images.clear();
      images.resize(count);
      if (nearest.capacity() < count) nearest.clear();
      nearest.resize(count);
    }
    MoveVoxels();
    if (cancelled) return absl::CancelledError("median interrupted");
    if (jump <= 0) return absl::OkStatus();
    FillGaps();
    if (cancelled) return absl::CancelledError("median interrupted");
    return absl::OkStatus();
  }

 private:
  // Rows of the source and the moving set around one row, with the ranks
  // of the moving voxels; the neighbour tests below are bit tests on these
  // (null outside the lattice or, for ranks, outside the moving box, where
  // nothing moves).
  struct Rows {
    const uint64_t* src = nullptr;
    const uint64_t* mov = nullptr;
    const uint32_t* first = nullptr;  // MemberRanks::first at word 0
  };
  // Neighbours in -x, +x, -y, +y, -z, +z order.
  static constexpr int kStep[6][3] = {{-1, 0, 0}, {1, 0, 0},  {0, -1, 0},
                                      {0, 1, 0},  {0, 0, -1}, {0, 0, 1}};

  void Poll(uint64_t units) {
    if (intr.WasInterrupted(done.fetch_add(units) + units, work)) cancelled = true;
  }

  // Every moving voxel's image into `out` (and, for the gap filling, into
  // `images` and `nearest` by rank).
  void MoveVoxels() {
    tbb::parallel_for(slabs, [&](const tbb::blocked_range<int>& r) {
      if (cancelled) return;
      for (int z = r.begin(); z < r.end(); ++z)
        for (int y = mbox->min.y; y <= mbox->max.y; ++y) {
          const uint64_t* row = moving.Row(y, z);
          uint32_t rank = ranks.first[ranks.Slot(y, z)];
          // The field's row (y, z), indexed by x - box.min.x: the moving box
          // lies in the field's box. Found once per row, not per voxel.
          const PackedVoxel* field_row = field.nearest.data() + field.Index(field.box.min.x, y, z);
          for (int w = ranks.w0; w < ranks.w0 + ranks.nw; ++w)
            for (uint64_t bits = row[w]; bits; bits &= bits - 1, ++rank) {
              const int x = (w << 6) + std::countr_zero(bits);
              const PackedVoxel pf = field_row[x - field.box.min.x];
              // An empty target leaves nothing to move toward: keep the voxel.
              const Int3 m =
                  pf == kNoVoxel ? Int3{x, y, z} : Midpoint({x, y, z}, UnpackVoxel(pf), round_up);
              SetAtomic(out, m.x, m.y, m.z);
              if (jump > 0) {
                images[rank] = PackVoxel(m);
                nearest[rank] = pf;
              }
            }
        }
      Poll(r.size());
    });
  }

  Rows RowsAt(int y, int z) const {
    Rows r;
    if (y < 0 || z < 0 || y >= res.y || z >= res.z) return r;
    r.src = source.Row(y, z);
    r.mov = moving.Row(y, z);
    if (y >= mbox->min.y && y <= mbox->max.y && z >= mbox->min.z && z <= mbox->max.z)
      r.first = ranks.first + ranks.Slot(y, z) - ranks.w0;
    return r;
  }
  static uint64_t Bit(const uint64_t* row, int x) { return (row[x >> 6] >> (x & 63)) & 1; }
  // Rank of moving voxel x of a row.
  static uint32_t RankIn(const Rows& r, int x) {
    const int w = x >> 6;
    return r.first[w] + PopCount(r.mov[w] & ((uint64_t{1} << (x & 63)) - 1));
  }

  // Fills the image of the cube a + {0,1}^3 when it lies wholly in the
  // source and the nearest-point map is continuous over it. `rows` are
  // rows (y, z), (y + 1, z), (y, z + 1) and (y + 1, z + 1) of a = (x, y, z).
  void FillCube(Int3 a, const Rows (&rows)[4]) {
    if (a.x + 1 >= res.x) return;
    Int3 img[8];
    Motion motion[8];
    Int3 flo{1 << 30, 1 << 30, 1 << 30}, fhi{-1, -1, -1};
    for (int c = 0; c < 8; ++c) {
      const Rows& row = rows[c >> 1];
      const int x = a.x + (c & 1);
      if (!row.src || !Bit(row.src, x)) return;
      const Int3 v{x, a.y + ((c >> 1) & 1), a.z + (c >> 2)};
      Int3 f = v;  // target members stay put
      img[c] = v;
      if (Bit(row.mov, x)) {
        const uint32_t rank = RankIn(row, x);
        f = UnpackVoxel(nearest[rank]);
        img[c] = UnpackVoxel(images[rank]);
      }
      motion[c] = MotionOf(v, f);
      flo = {std::min(flo.x, f.x), std::min(flo.y, f.y), std::min(flo.z, f.z)};
      fhi = {std::max(fhi.x, f.x), std::max(fhi.y, f.y), std::max(fhi.z, f.z)};
    }
    if (Chebyshev(flo, fhi) > jump) return;
    // The tetrahedra only add voxels inside the corners' images' box: when
    // the median has already set all of those (common: neighbouring cubes'
    // images overlap), the fill skips its 28 coherence tests. They run at
    // the first voxel the fill would add (most missing voxels of a box lie
    // outside the cube's image), and the box is scanned once.
    auto coherent = [&] {
      for (const CornerPair& p : kCornerPairs)
        if (!Coherent(motion[p.i], motion[p.j], p.d)) return false;
      return true;
    };
    FillCubeImage(img, CubeImageBox(img, res), out, coherent);
  }

  // The pairs of moving voxel (x, rank) with its neighbours: bridges
  // and, when it stretches toward +x, +y or +z, the cube fill.
  // The neighbours to pair with come from the pretest's words (bit b
  // of still[k] | moves[k]): source voxels inside the lattice, moving
  // ones only along +x, +y and +z (the others pair from there).
  void Bridge(int x, int y, int z, uint32_t rank, int b, const uint64_t (&still)[6],
              const uint64_t (&moves)[6], const Rows& here, const Rows (&around)[6]) {
    const Int3 a{x, y, z};
    const Int3 m = UnpackVoxel(images[rank]);
    const Int3 f = UnpackVoxel(nearest[rank]);
    bool stretched = false;
    for (int k = 0; k < 6; ++k) {
      if (!(((still[k] | moves[k]) >> b) & 1)) continue;
      const Rows& nr = around[k];
      const int nx = x + kStep[k][0];
      const bool n_moving = (moves[k] >> b) & 1;
      const Int3 n{nx, y + kStep[k][1], z + kStep[k][2]};
      // Along x a moving neighbour is the next rank.
      const uint32_t rn = !n_moving ? 0 : k == 1 ? rank + 1 : RankIn(nr, nx);
      const Int3 mn = n_moving ? UnpackVoxel(images[rn]) : n;
      const int gap = Chebyshev(m, mn);
      if (gap < 2) continue;
      const Int3 fn = n_moving ? UnpackVoxel(nearest[rn]) : n;
      if (Chebyshev(f, fn) > jump || !Coherent(a, f, n, fn)) continue;
      if (k & 1) stretched = true;
      for (int s = 1; s < gap; ++s) {
        const double t = double(s) / gap;
        SetAtomic(out, m.x + RoundHalfAway((mn.x - m.x) * t), m.y + RoundHalfAway((mn.y - m.y) * t),
                  m.z + RoundHalfAway((mn.z - m.z) * t));
      }
    }
    if (stretched) {
      const Rows cube_rows[4] = {here, around[3], around[5], RowsAt(y + 1, z + 1)};
      FillCube(a, cube_rows);
    }
  }

  // The bridges and cube fills of the moving voxels of row (y, z).
  void FillRowGaps(int y, int z, gap::NeedFn need_of) {
    const Rows here = RowsAt(y, z);
    bool any = false;
    for (int w = mbox->min.x >> 6; w <= mbox->max.x >> 6 && !any; ++w) any = here.mov[w];
    if (!any) return;
    const Rows around[6] = {
        here, here, RowsAt(y - 1, z), RowsAt(y + 1, z), RowsAt(y, z - 1), RowsAt(y, z + 1)};
    const int w_first = mbox->min.x >> 6, w_last = mbox->max.x >> 6;
    const int words = moving.words_per_row();
    auto word_of = [&](const uint64_t* row, int w) {
      return row && w >= 0 && w < words ? row[w] : uint64_t{0};
    };
    for (int w = w_first; w <= w_last; ++w) {
      const uint64_t mov = here.mov[w];
      if (!mov) continue;
      // Bit b of these words stands for voxel x = 64 w + b and tells
      // whether its neighbour in direction k is a source voxel that
      // stays put (`still`) or one that moves (`moves`, +x, +y and +z
      // only: pairs with -x, -y and -z moving neighbours are handled
      // from those).
      const int room = res.x - 1 - (w << 6);  // bits b with x + 1 < res.x
      const uint64_t has_hi = room >= 64 ? ~uint64_t{0} : (uint64_t{1} << room) - 1;
      const uint64_t src_lo = (here.src[w] << 1) | (word_of(here.src, w - 1) >> 63);
      const uint64_t mov_lo = (mov << 1) | (word_of(here.mov, w - 1) >> 63);
      const uint64_t src_hi = ((here.src[w] >> 1) | (word_of(here.src, w + 1) << 63)) & has_hi;
      const uint64_t mov_hi = ((mov >> 1) | (word_of(here.mov, w + 1) << 63)) & has_hi;
      uint64_t still[6], moves[6] = {0, mov_hi, 0, 0, 0, 0};
      still[0] = src_lo & ~mov_lo;
      still[1] = src_hi & ~mov_hi;
      for (int k = 2; k < 6; ++k) {
        const uint64_t s = word_of(around[k].src, w), mv = word_of(around[k].mov, w);
        still[k] = s & ~mv;
        if (k & 1) moves[k] = mv;
      }
      // The pretest (gap_pretest.h) leaves the voxels that may need a
      // bridge: about one in five.
      const uint32_t rank0 = here.first[w];
      gap::Word g;
      g.mov = mov;
      std::copy_n(still, 6, g.still);
      g.moves_x = moves[1];
      g.moves_y = moves[3];
      g.moves_z = moves[5];
      g.images = images.data() + rank0;
      if (moves[3]) g.images_y = images.data() + around[3].first[w];
      if (moves[5]) g.images_z = images.data() + around[5].first[w];
      g.x0 = w << 6;
      g.y = y;
      g.z = z;
      for (uint64_t need = need_of(g); need; need &= need - 1) {
        const int b = std::countr_zero(need);
        const uint32_t rank = rank0 + PopCount(mov & ((uint64_t{1} << b) - 1));
        Bridge((w << 6) + b, y, z, rank, b, still, moves, here, around);
      }
    }
  }

  // Bridges and cube fills between the images of neighbouring voxels.
  void FillGaps() {
    const gap::NeedFn need_of = gap::NeedKernel();
    tbb::parallel_for(slabs, [&](const tbb::blocked_range<int>& r) {
      if (cancelled) return;
      for (int z = r.begin(); z < r.end(); ++z)
        for (int y = mbox->min.y; y <= mbox->max.y; ++y) FillRowGaps(y, z, need_of);
      Poll(r.size());
    });
  }

  const VoxelSet& moving;
  const VoxelSet& source;
  const FeatureField& field;
  VoxelSet& out;
  Interrupter& intr;
  const Int3 res;
  const unsigned round_up;
  const int jump;
  const VoxelBox* const mbox;
  MemberRanks ranks;
  const uint32_t count;
  std::vector<PackedVoxel, BigBufferAllocator<PackedVoxel>>& images;
  std::vector<PackedVoxel, BigBufferAllocator<PackedVoxel>>& nearest;
  const uint64_t work;
  const tbb::blocked_range<int> slabs;
  std::atomic<bool> cancelled{false};
  std::atomic<uint64_t> done{0};
};

// Adds { Midpoint(a, nearest(a)) : a in moving } to `out`, where `moving`
// is the part of `source` outside the target set and `field` holds nearest
// target voxels at least at every moving voxel. Members of `source` that
// are not moving lie in the target and map to themselves.
//
// Gap filling: where the images of face-adjacent voxels are two or more
// voxels apart but their nearest points are close and in agreeing
// directions (the nearest-point map is continuous there, so the exact image
// is solid), the segment between the images is drawn, and the image of the
// voxel cube spanned from `a` is filled as six tetrahedra. The images and
// nearest points of the moving voxels are kept in compact arrays indexed
// by rank (MemberRanks) for the neighbour checks.
absl::Status AddMidpoints(const VoxelSet& moving, const VoxelSet& source, const FeatureField& field,
                          const MedianOptions& options, uint64_t seed, const VoxelBox& moving_box,
                          MovingBuffers& ws, VoxelSet& out, Interrupter& intr) {
  return MidpointPass(moving, source, field, options, seed, moving_box, ws, out, intr).Run();
}

// ws.field = `target`'s feature transform, computed only over the box the
// voxels of `moving` need and queried there; timed as nearest-point work.
// `target_box` is the target's bounding box when known (else it is scanned).
absl::Status NearestFieldFor(const VoxelSet& target, const std::optional<VoxelBox>& target_box,
                             const VoxelSet& moving, const VoxelBox& moving_box, Vec3 h,
                             SetMapWorkspace& ws) {
  const auto t0 = Clock::now();
  FeatureTransformOptions fo;
  fo.box = moving_box;
  fo.queries = &moving;
  fo.set_box = target_box;
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
  std::optional<VoxelBox> a, b;  // of a \ b and b \ a
  // Of the sets a and b themselves (b's only with both_sides): the
  // transforms need them, and they come at little cost from this pass
  // instead of a serial scan of the lattice each.
  std::optional<VoxelBox> all_a, all_b;
};
SplitBoxes SplitPair(const VoxelSet& a, const VoxelSet& b, bool both_sides, VoxelSet& out,
                     VoxelSet& moving_a, VoxelSet& moving_b) {
  const Int3 res = a.resolution();
  for (VoxelSet* s : {&out, &moving_a, &moving_b})
    if (!(s->resolution() == res) || s->words().size() != a.words().size()) *s = VoxelSet(res);
  const int words = a.words_per_row();
  constexpr int kSlab = 8;
  const int slabs = (res.z + kSlab - 1) / kSlab;
  std::vector<BoxAccumulator> box_a(static_cast<size_t>(slabs)), box_b(box_a), box_o(box_a);
  tbb::parallel_for(tbb::blocked_range<int>(0, slabs), [&](const tbb::blocked_range<int>& r) {
    for (int sl = r.begin(); sl < r.end(); ++sl)
      for (int z = sl * kSlab; z < std::min(res.z, (sl + 1) * kSlab); ++z)
        for (int y = 0; y < res.y; ++y) {
          const uint64_t* ra = a.Row(y, z);
          const uint64_t* rb = b.Row(y, z);
          uint64_t* o = out.MutableRow(y, z);
          uint64_t* ma = moving_a.MutableRow(y, z);
          uint64_t* mb = moving_b.MutableRow(y, z);
          uint64_t any = 0;
          for (int w = 0; w < words; ++w) any |= ra[w] | rb[w];
          if (!any) {  // most rows: nothing to split, and no box to grow
            std::fill_n(o, words, 0);
            std::fill_n(ma, words, 0);
            if (both_sides) std::fill_n(mb, words, 0);
            continue;
          }
          for (int w = 0; w < words; ++w) {
            o[w] = ra[w] & rb[w];
            ma[w] = ra[w] & ~rb[w];
          }
          box_a[size_t(sl)].AddRow(ma, words, y, z);
          box_o[size_t(sl)].AddRow(o, words, y, z);
          if (!both_sides) continue;
          for (int w = 0; w < words; ++w) mb[w] = rb[w] & ~ra[w];
          box_b[size_t(sl)].AddRow(mb, words, y, z);
        }
  });
  BoxAccumulator all_a, all_b, all_o;
  for (int sl = 0; sl < slabs; ++sl) {
    if (box_a[size_t(sl)].any) all_a.Add(box_a[size_t(sl)].box);
    if (box_b[size_t(sl)].any) all_b.Add(box_b[size_t(sl)].box);
    if (box_o[size_t(sl)].any) all_o.Add(box_o[size_t(sl)].box);
  }
  BoxAccumulator set_a = all_o, set_b = all_o;  // a = (a ∩ b) ∪ (a \ b), and so for b
  if (all_a.any) set_a.Add(all_a.box);
  if (all_b.any) set_b.Add(all_b.box);
  return {all_a.Get(), all_b.Get(), set_a.Get(), both_sides ? set_b.Get() : std::nullopt};
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
  if (b_field && both_sides && boxes.a && boxes.b) {
    // The two halves overlap: a's voxels move with b's ready transform
    // while a's transform is computed for b's voxels (separate buffers; the
    // only shared output is `out`, which both only add bits to). Running
    // them side by side lets the threads fill each other's serial parts
    // and uneven ends of parallel loops.
    absl::Status moved_a, field_b;
    tbb::parallel_invoke(
        [&] {
          moved_a =
              AddMidpoints(ws.moving_a, a, *b_field, options, seed, *boxes.a, ws.side_a, out, intr);
        },
        [&] { field_b = NearestFieldFor(a, boxes.all_a, ws.moving_b, *boxes.b, h, ws); });
    NIMBUS_RETURN_IF_ERROR(moved_a);
    NIMBUS_RETURN_IF_ERROR(field_b);
    return AddMidpoints(ws.moving_b, b, ws.field, options, seed, *boxes.b, ws.side_b, out, intr);
  }
  if (boxes.a) {
    const FeatureField* field = b_field;
    if (!field) {
      NIMBUS_RETURN_IF_ERROR(NearestFieldFor(b, boxes.all_b, ws.moving_a, *boxes.a, h, ws));
      field = &ws.field;
    }
    NIMBUS_RETURN_IF_ERROR(
        AddMidpoints(ws.moving_a, a, *field, options, seed, *boxes.a, ws.side_a, out, intr));
  }
  if (!both_sides) return absl::OkStatus();
  if (boxes.b) {
    NIMBUS_RETURN_IF_ERROR(NearestFieldFor(a, boxes.all_a, ws.moving_b, *boxes.b, h, ws));
    NIMBUS_RETURN_IF_ERROR(
        AddMidpoints(ws.moving_b, b, ws.field, options, seed, *boxes.b, ws.side_b, out, intr));
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
