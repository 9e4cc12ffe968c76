#include "core/sets/set_maps.h"

#include <gtest/gtest.h>

#include <cmath>
#include <deque>

#include "core/sets/cube_image.h"
#include "core/sets/feature_transform.h"
#include "core/base/random.h"
#include "core/sets/shapes.h"
#include "core/grid/voxel_set.h"
#include "core/sets/voxelize.h"
#include "tests/support/median_reference.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

GridFrame Cube(int n) { return {{n, n, n}, {{-1, -1, -1}, {1, 1, 1}}}; }

VoxelSet RandomSet(Int3 r, double p, Rng& rng) {
  VoxelSet s(r);
  for (int z = 0; z < r.z; ++z)
    for (int y = 0; y < r.y; ++y)
      for (int x = 0; x < r.x; ++x)
        if (rng.Uniform() < p) s.Set(x, y, z);
  return s;
}

// Empty voxels not connected (6-neighbourhood) to the lattice border.
int64_t EnclosedEmptyVoxels(const VoxelSet& s) {
  const Int3 r = s.resolution();
  VoxelSet reached(r);
  std::deque<Int3> queue;
  for (int z = 0; z < r.z; ++z)
    for (int y = 0; y < r.y; ++y)
      for (int x = 0; x < r.x; ++x) {
        const bool border =
            x == 0 || y == 0 || z == 0 || x == r.x - 1 || y == r.y - 1 || z == r.z - 1;
        if (border && !s.Get(x, y, z)) {
          reached.Set(x, y, z);
          queue.push_back({x, y, z});
        }
      }
  while (!queue.empty()) {
    const Int3 v = queue.front();
    queue.pop_front();
    const Int3 steps[6] = {{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}, {0, 0, -1}};
    for (const Int3& d : steps) {
      const Int3 n{v.x + d.x, v.y + d.y, v.z + d.z};
      if (!s.InBounds(n) || s.Get(n) || reached.Get(n)) continue;
      reached.Set(n);
      queue.push_back(n);
    }
  }
  return r.Volume() - s.Count() - reached.Count();
}

const VoxelSet& CowAt48() {
  static const VoxelSet cow = [] {
    VoxelizeOptions o;
    o.fit = true;
    return LoadAndVoxelize(testing::SourcePath("examples/meshes/cow.obj"), Cube(48), o)->interior;
  }();
  return cow;
}

// ---------------------------------------------------------------- VoxelSet

TEST(VoxelSet, CountsBoxesAndAlgebra) {
  VoxelSet a({70, 5, 4}), b({70, 5, 4});
  EXPECT_TRUE(a.Empty());
  EXPECT_FALSE(a.BoundingBox().has_value());
  a.SetSpan(3, 66, 2, 1);  // crosses a word boundary
  b.Set(66, 2, 1);
  b.Set(69, 4, 3);
  EXPECT_EQ(a.Count(), 64);
  EXPECT_EQ((a | b).Count(), 65);
  EXPECT_EQ((a & b).Count(), 1);
  EXPECT_EQ((a - b).Count(), 63);
  EXPECT_EQ(*(a | b).BoundingBox(), (VoxelBox{{3, 2, 1}, {69, 4, 3}}));
  EXPECT_TRUE(a == a);
  EXPECT_FALSE(a == b);
  VoxelSet full({70, 5, 4});
  full.Fill();
  EXPECT_EQ(full.Count(), 70 * 5 * 4);
}

TEST(VoxelSet, ShiftAndBoundary) {
  const GridFrame f = Cube(20);
  const VoxelSet box = *BoxSet(f, {{-0.5, -0.5, -0.5}, {0.5, 0.5, 0.5}});  // 10^3 voxels
  EXPECT_EQ(box.Count(), 1000);
  const VoxelSet moved = ShiftSet(box, {-7, 3, 70});
  EXPECT_TRUE(moved.Empty());  // pushed off the lattice in z
  const VoxelSet s = ShiftSet(box, {-7, 3, 1});
  EXPECT_EQ(s.Count(), 8 * 10 * 10);  // two columns fall off at x < 0
  EXPECT_EQ(*s.BoundingBox(), (VoxelBox{{0, 8, 6}, {7, 17, 15}}));
  EXPECT_EQ(BoundaryOf(box).Count(), 1000 - 512);
}

// ---------------------------------------------------------------- shapes

TEST(Shapes, VolumesMatchFormulas) {
  const GridFrame f = Cube(64);
  const double voxel = std::pow(2.0 / 64, 3);
  const double r = 0.6;
  EXPECT_NEAR(SphereSet(f, {0.05, -0.1, 0}, r)->Count() * voxel, 4.0 / 3 * M_PI * r * r * r, 0.02);
  EXPECT_NEAR(TorusSet(f, {0, 0, 0}, {1, 1, 0}, 0.6, 0.2)->Count() * voxel,
              2 * M_PI * M_PI * 0.6 * 0.04, 0.02);
  EXPECT_EQ(BoxSet(f, {{-1, -1, -1}, {0, 0, 0}})->Count(), 32 * 32 * 32);
  EXPECT_FALSE(SphereSet(f, {0, 0, 0}, -1).ok());
  EXPECT_FALSE(TorusSet(f, {0, 0, 0}, {0, 0, 0}, 1, 0.1).ok());
}

TEST(Shapes, RandomBallsAreSeededAndInside) {
  const GridFrame f = Cube(48);
  const VoxelSet& cow = CowAt48();
  RandomBallsOptions o;
  o.count = 12;
  o.min_radius = 0.05;
  o.max_radius = 0.1;
  o.seed = 5;
  const VoxelSet a = *RandomBallsInside(cow, f, o);
  EXPECT_EQ(a, *RandomBallsInside(cow, f, o));
  o.seed = 6;
  EXPECT_FALSE(a == *RandomBallsInside(cow, f, o));
  // Centres lie inside the cow (thin at this resolution), so a good part of
  // every ball does too.
  EXPECT_GT((a & cow).Count(), a.Count() / 2);
  o.clip_to_region = true;
  const VoxelSet clipped = *RandomBallsInside(cow, f, o);
  EXPECT_EQ((clipped - cow).Count(), 0);
  EXPECT_FALSE(RandomBallsInside(VoxelSet(f.resolution), f, o).ok());
}

// ---------------------------------------------------------------- feature transform

TEST(FeatureTransform, MatchesBruteForceOnRandomSets) {
  Rng rng(11, 0);
  for (int trial = 0; trial < 25; ++trial) {
    const Int3 r{1 + int(rng.Next() % 13), 1 + int(rng.Next() % 9), 1 + int(rng.Next() % 11)};
    VoxelSet s = RandomSet(r, rng.Uniform(0.005, 0.3), rng);
    if (s.Empty()) s.Set(r.x - 1, 0, r.z / 2);
    const Vec3 h{rng.Uniform(0.3, 2), rng.Uniform(0.3, 2), rng.Uniform(0.3, 2)};
    const absl::StatusOr<FeatureField> field = ComputeFeatureTransform(s, h);
    ASSERT_TRUE(field.ok());
    for (int z = 0; z < r.z; ++z)
      for (int y = 0; y < r.y; ++y)
        for (int x = 0; x < r.x; ++x) {
          double best = 1e300;
          s.ForEach([&](int a, int b, int c) {
            best = std::min(best, SquaredDistance({x, y, z}, {a, b, c}, h));
          });
          const Int3 got = UnpackVoxel(field->At(x, y, z));
          ASSERT_TRUE(s.Contains(got)) << "trial " << trial;
          ASSERT_NEAR(SquaredDistance({x, y, z}, got, h), best, 1e-9)
              << "trial " << trial << " at " << x << "," << y << "," << z;
        }
  }
}

TEST(FeatureTransform, RestrictedBoxAgreesWithWholeLattice) {
  Rng rng(12, 0);
  const Int3 r{40, 33, 27};
  const VoxelSet s = RandomSet(r, 0.002, rng);
  const VoxelSet queries = RandomSet(r, 0.05, rng) - s;
  const Vec3 h{1, 0.7, 1.6};
  const FeatureField whole = *ComputeFeatureTransform(s, h);
  FeatureTransformOptions o;
  o.box = queries.BoundingBox();
  o.queries = &queries;
  FeatureField part;
  ASSERT_TRUE(ComputeFeatureTransform(s, h, o, part).ok());
  queries.ForEach([&](int x, int y, int z) { ASSERT_EQ(part.At(x, y, z), whole.At(x, y, z)); });
}

// With voxel sizes whose squares are small multiples of one power of two,
// the transform's arithmetic is exact, and the nearest member it returns is
// the lowest (z, y, x) among the equally near ones: the rule that lets it
// drop sites out of reach of queries near the set.
Int3 LowestNearest(const VoxelSet& s, Int3 v, Vec3 h) {
  double best = 1e300;
  Int3 arg{-1, -1, -1};
  s.ForEach([&](int x, int y, int z) {  // row order: z, then y, then x ascending
    const double d = SquaredDistance(v, {x, y, z}, h);
    if (d < best) {
      best = d;
      arg = {x, y, z};
    }
  });
  return arg;
}

TEST(FeatureTransform, QueriesNearTheSetGiveTheWholeLatticeAnswer) {
  Rng rng(13, 0);
  const Vec3 sizes[3] = {{0.0625, 0.0625, 0.0625}, {0.0625, 0.125, 0.25}, {0.375, 0.25, 0.25}};
  for (int trial = 0; trial < 12; ++trial) {
    // Some lattices rows of several words wide (the growth's carries).
    const int wide = trial % 4 == 1 ? 150 : 0;
    const Int3 r{20 + wide + int(rng.Next() % 50), 10 + int(rng.Next() % 30),
                 10 + int(rng.Next() % 30)};
    const VoxelSet s = RandomSet(r, rng.Uniform(0.001, 0.02), rng);
    if (s.Empty()) continue;
    // Queries at every distance: most within a few voxels of the set (the
    // pruned case), a few far (columns that keep all their sites).
    VoxelSet near = s;
    for (int grow = int(rng.Next() % 4); grow >= 0; --grow) {
      const VoxelSet was = near;
      for (const Int3 d : {Int3{1, 0, 0}, Int3{-1, 0, 0}, Int3{0, 1, 0}, Int3{0, -1, 0},
                           Int3{0, 0, 1}, Int3{0, 0, -1}})
        near = near | ShiftSet(was, d);
    }
    const VoxelSet queries = ((near & RandomSet(r, 0.3, rng)) | RandomSet(r, 0.002, rng)) - s;
    if (queries.Empty()) continue;
    const Vec3 h = sizes[trial % 3];
    const FeatureField whole = *ComputeFeatureTransform(s, h);
    FeatureTransformOptions o;
    o.box = queries.BoundingBox();
    o.queries = &queries;
    FeatureField part;
    ASSERT_TRUE(ComputeFeatureTransform(s, h, o, part).ok());
    // The set's box given by the caller (as the median does) changes nothing.
    o.set_box = s.BoundingBox();
    FeatureField told;
    ASSERT_TRUE(ComputeFeatureTransform(s, h, o, told).ok());
    ASSERT_TRUE(told.box.min == part.box.min && told.box.max == part.box.max);
    queries.ForEach([&](int x, int y, int z) {
      ASSERT_EQ(part.At(x, y, z), whole.At(x, y, z)) << "trial " << trial;
      ASSERT_EQ(told.At(x, y, z), whole.At(x, y, z)) << "trial " << trial;
      ASSERT_EQ(UnpackVoxel(whole.At(x, y, z)), LowestNearest(s, {x, y, z}, h))
          << "trial " << trial << " at " << x << "," << y << "," << z;
    });
  }
}

TEST(FeatureTransform, HausdorffDistance) {
  const GridFrame f = Cube(32);
  const Vec3 h = f.VoxelSize();
  const VoxelSet a = *BoxSet(f, {{-0.5, -0.5, -0.5}, {0.5, 0.5, 0.5}});
  const VoxelSet b = ShiftSet(a, {3, 0, 0});
  EXPECT_NEAR(*HausdorffDistance(a, b, h), 3 * h.x, 1e-12);
  EXPECT_NEAR(*HausdorffDistance(a, a, h), 0, 1e-12);
  EXPECT_NEAR(*DirectedHausdorff(a & b, a, h), 0, 1e-12);
}

// ---------------------------------------------------------------- median

// Voxel sets given by hand, and the oracle's verdict on an engine answer.
using testing::AdmittingRoundings;
using testing::VoxelSetOf;

// Sparse random sets on a frame with unequal voxel sizes, so nearest points
// depend on the world metric, not on index distances.
const GridFrame& Skewed() {
  static const GridFrame f{{20, 18, 16}, {{0, 0, 0}, {2.0, 2.34, 2.72}}};  // h = .1, .13, .17
  return f;
}

TEST(Median, FixesItsCondensationSet) {
  const GridFrame f = Cube(48);
  const VoxelSet& cow = CowAt48();
  EXPECT_EQ(*Median(cow, cow, f), cow);
  const VoxelSet ball = *SphereSet(f, {0.2, 0.1, -0.3}, 0.4);
  EXPECT_EQ(*Median(ball, ball, f), ball);
  EXPECT_EQ(*LeftMedian(cow, cow, f), cow);
  RotatedMedianOptions ro;
  ro.degrees_per_unit = 60;
  EXPECT_EQ(*RotatedMedian(cow, cow, f, ro), cow);

  // A set other than C moves, by exact midpoints, and the iteration of
  // f_C reaches C itself and stays there. C is two voxels, I one voxel
  // nearer to C's second voxel (squared distances 68 and 100); every
  // coordinate sum is even, so no rounding is involved:
  //   D_I(C) = {mid((10,12,4), (12,4,4))} = {(11,8,4)}
  //   D_C(I) = {mid((4,4,4), (10,12,4)), mid((12,4,4), (10,12,4))} = {(7,8,4), (11,8,4)}
  const GridFrame small = Cube(16);
  const Int3 r = small.resolution;
  const VoxelSet c = VoxelSetOf(r, {{4, 4, 4}, {12, 4, 4}});
  VoxelSet set = VoxelSetOf(r, {{10, 12, 4}});
  EXPECT_EQ(*Median(set, c, small), VoxelSetOf(r, {{7, 8, 4}, {11, 8, 4}}));
  MedianOptions no_fill;
  no_fill.bridge_max_jump = 0;
  const SetMapPtr map = *MakeMedianMap(small, c, no_fill);
  SetMapWorkspace ws;
  VoxelSet next;
  int steps = 0;
  for (; steps < 40 && !(set == c); ++steps) {
    ws.seed = uint64_t(steps);
    ASSERT_TRUE(map->Apply(set, next, ws).ok());
    // Each step is one of the brute-force medians (the seed picks the rounding).
    ASSERT_FALSE(AdmittingRoundings(set, c, small.VoxelSize(), true, next).empty())
        << "step " << steps;
    std::swap(set, next);
  }
  EXPECT_EQ(set, c) << "not condensed after " << steps << " steps";
  EXPECT_GE(steps, 3);  // the distance 8 at least halves per step
  for (uint64_t seed : {0, 1, 2}) {
    ws.seed = seed;
    ASSERT_TRUE(map->Apply(c, next, ws).ok());
    EXPECT_EQ(next, c);
  }
}

TEST(Median, MatchesBruteForceMidpointsOfNearestVoxels) {
  // Distinct random sets with voxels in common; every voxel of A \ B goes
  // halfway to its nearest voxel of B and back. One rounding for all.
  Rng rng(31, 0);
  const GridFrame& f = Skewed();
  const Vec3 h = f.VoxelSize();
  MedianOptions o;
  o.bridge_max_jump = 0;
  for (int trial = 0; trial < 12; ++trial) {
    const VoxelSet a = RandomSet(f.resolution, 0.01, rng);
    VoxelSet b = RandomSet(f.resolution, 0.004, rng) | (a & RandomSet(f.resolution, 0.3, rng));
    if (a.Empty() || b.Empty()) continue;
    o.seed = uint64_t(trial);
    const VoxelSet left = *LeftMedian(a, b, f, o);
    const VoxelSet both = *Median(a, b, f, o);
    EXPECT_FALSE(AdmittingRoundings(a, b, h, false, left).empty()) << "trial " << trial;
    EXPECT_FALSE(AdmittingRoundings(a, b, h, true, both).empty()) << "trial " << trial;
    EXPECT_FALSE(left == both) << "trial " << trial;
  }
}

TEST(Median, RoundsFaceMidpointsBySeedAlongEachAxis) {
  // (1,1,1) and (4,6,8): every coordinate sum is odd, so the median is the
  // single voxel (2|3, 3|4, 4|5) -- the same from both sides -- and each
  // axis goes up for some seeds and down for others.
  const GridFrame f = Cube(16);
  const VoxelSet a = VoxelSetOf(f.resolution, {{1, 1, 1}});
  const VoxelSet b = VoxelSetOf(f.resolution, {{4, 6, 8}});
  int ups[3] = {0, 0, 0};
  const int seeds = 64;
  for (int seed = 0; seed < seeds; ++seed) {
    MedianOptions o;
    o.seed = uint64_t(seed);
    const VoxelSet m = *Median(a, b, f, o);
    ASSERT_EQ(m.Count(), 1) << "seed " << seed;
    const Int3 v = m.BoundingBox()->min;
    ASSERT_TRUE(v.x == 2 || v.x == 3) << v.x;
    ASSERT_TRUE(v.y == 3 || v.y == 4) << v.y;
    ASSERT_TRUE(v.z == 4 || v.z == 5) << v.z;
    ups[0] += v.x == 3, ups[1] += v.y == 4, ups[2] += v.z == 5;
    EXPECT_EQ(*LeftMedian(a, b, f, o), m);
    EXPECT_EQ(*LeftMedian(b, a, f, o), m);
  }
  for (int axis = 0; axis < 3; ++axis) {
    EXPECT_GT(ups[axis], seeds / 5) << "axis " << axis;
    EXPECT_LT(ups[axis], seeds - seeds / 5) << "axis " << axis;
  }
}

TEST(Median, IsSymmetric) {
  const GridFrame f = Cube(48);
  const VoxelSet& cow = CowAt48();
  const VoxelSet ball = *SphereSet(f, {0.6, 0.6, 0.6}, 0.25);
  const VoxelSet torus = *TorusSet(f, {-0.2, 0, 0.1}, {0, 1, 1}, 0.5, 0.15);
  for (uint64_t seed : {0, 1, 2, 3}) {
    MedianOptions o;
    o.seed = seed;
    EXPECT_EQ(*Median(ball, cow, f, o), *Median(cow, ball, f, o));
    EXPECT_EQ(*Median(torus, ball, f, o), *Median(ball, torus, f, o));
  }
}

TEST(Median, AddsTheOtherSetMovedTowardTheFirst) {
  // One voxel A against three voxels B (no two touching, so no gap
  // filling): D_A(B) moves A halfway to B's nearest voxel (10,2,2), and
  // the symmetric half D_B(A) moves each voxel of B halfway to A.
  const GridFrame f = Cube(16);
  const Int3 r = f.resolution;
  const VoxelSet a = VoxelSetOf(r, {{2, 2, 2}});
  const VoxelSet b = VoxelSetOf(r, {{10, 2, 2}, {10, 4, 2}, {12, 6, 2}});
  const VoxelSet d_ab = VoxelSetOf(r, {{6, 2, 2}});
  const VoxelSet d_ba = VoxelSetOf(r, {{6, 2, 2}, {6, 3, 2}, {7, 4, 2}});
  EXPECT_EQ(*LeftMedian(a, b, f), d_ab);
  EXPECT_EQ(*LeftMedian(b, a, f), d_ba);
  EXPECT_EQ(*Median(a, b, f), d_ab | d_ba);
  EXPECT_EQ(*Median(b, a, f), d_ab | d_ba);
  // The same through the map f_B(A) = M(A, B).
  SetMapWorkspace ws;
  VoxelSet out;
  ASSERT_TRUE((*MakeMedianMap(f, b))->Apply(a, out, ws).ok());
  EXPECT_EQ(out, d_ab | d_ba);
}

TEST(Median, LeftMedianOfBoxesIsTheHalfwayBox) {
  // Two slabs along x: D_A(B) squeezes A to half its distance from B.
  const GridFrame f{{40, 8, 8}, {{0, 0, 0}, {40, 8, 8}}};
  const VoxelSet a = *BoxSet(f, {{20, 0, 0}, {30, 8, 8}});  // x = 20..29
  const VoxelSet b = *BoxSet(f, {{0, 0, 0}, {5, 8, 8}});    // x = 0..4
  const VoxelSet d = *LeftMedian(a, b, f);
  const VoxelBox box = *d.BoundingBox();
  EXPECT_EQ(box.min.x, 12);  // (20 + 4) / 2
  EXPECT_GE(box.max.x, 16);  // (29 + 4) / 2, rounded either way
  EXPECT_LE(box.max.x, 17);
  EXPECT_EQ(box.Size().y, 8);
  EXPECT_EQ(d.Count(), box.Volume());  // solid
}

TEST(Median, MapAgreesWithBruteForce) {
  // f_C(I) reads C's precomputed transform and computes I's over a
  // restricted box; the brute-force median knows nothing of either.
  Rng rng(32, 0);
  const GridFrame& f = Skewed();
  const Vec3 h = f.VoxelSize();
  MedianOptions o;
  o.bridge_max_jump = 0;
  const VoxelSet c = RandomSet(f.resolution, 0.006, rng);
  ASSERT_FALSE(c.Empty());
  const SetMapPtr map = *MakeMedianMap(f, c, o);
  for (uint64_t seed : {0, 7, 8}) {
    // A cluster in one corner, so C \ I needs only part of I's transform.
    VoxelSet start = *BoxSet(f, {{0.2, 0.26, 0.34}, {0.9, 1.1, 1.2}}) &
                     RandomSet(f.resolution, 0.2, rng);
    start |= c & RandomSet(f.resolution, 0.3, rng);
    SetMapWorkspace ws;
    ws.seed = seed;
    VoxelSet out;
    ASSERT_TRUE(map->Apply(start, out, ws).ok());
    EXPECT_FALSE(AdmittingRoundings(start, c, h, true, out).empty()) << "seed " << seed;
    EXPECT_EQ(ws.stats.applications, 1u);
    o.seed = seed;
    EXPECT_EQ(out, *Median(start, c, f, o));
  }
}

TEST(Median, IterationConvergesToTheCondensationSet) {
  const GridFrame f = Cube(48);
  const Vec3 h = f.VoxelSize();
  const VoxelSet& cow = CowAt48();
  const SetMapPtr map = *MakeMedianMap(f, cow);
  SetMapWorkspace ws;
  VoxelSet set = *SphereSet(f, {0.75, 0.75, 0.75}, 0.2), next;
  double previous = *HausdorffDistance(set, cow, h);
  ASSERT_GT(previous, 15 * h.x);
  for (int k = 0; k < 24; ++k) {
    ws.seed = uint64_t(k);
    ASSERT_TRUE(map->Apply(set, next, ws).ok());
    std::swap(set, next);
    const double d = *HausdorffDistance(set, cow, h);
    if (k < 4) {
      EXPECT_LT(d, 0.75 * previous) << "step " << k;  // roughly halves
    }
    previous = d;
  }
  EXPECT_LE(previous, h.x + 1e-12);
}

TEST(Median, RotatedMedianConvergesAndDependsOnTheAngle) {
  const GridFrame f = Cube(48);
  const Vec3 h = f.VoxelSize();
  const VoxelSet& cow = CowAt48();
  const VoxelSet start = *SphereSet(f, {0.7, -0.7, 0.6}, 0.2);
  RotatedMedianOptions slow, fast;
  slow.degrees_per_unit = 20;
  fast.degrees_per_unit = 90;
  fast.axis = slow.axis = {0, 1, 0};
  const SetMapPtr a = *MakeRotatedMedianMap(f, cow, slow);
  const SetMapPtr b = *MakeRotatedMedianMap(f, cow, fast);
  SetMapWorkspace ws;
  VoxelSet sa = start, sb = start, next;
  for (int k = 0; k < 30; ++k) {
    ws.seed = uint64_t(k);
    ASSERT_TRUE(a->Apply(sa, next, ws).ok());
    std::swap(sa, next);
    ASSERT_TRUE(b->Apply(sb, next, ws).ok());
    std::swap(sb, next);
    if (k == 1) {
      EXPECT_FALSE(sa == sb);  // the paths differ
    }
  }
  EXPECT_LE(*HausdorffDistance(sa, cow, h), 2.5 * h.x);
  EXPECT_LE(*HausdorffDistance(sb, cow, h), 2.5 * h.x);
}

TEST(Median, FillsGapsWhereTheNearestPointMapIsContinuous) {
  // A ball inside a spherical shell: the nearest-point map spreads the ball
  // over a thick shell, so the forward image alone is porous.
  const GridFrame f = Cube(48);
  const VoxelSet shell = *SphereSet(f, {0, 0, 0}, 0.9) - *SphereSet(f, {0, 0, 0}, 0.7);
  const VoxelSet ball = *SphereSet(f, {0.05, 0.02, 0}, 0.4);
  MedianOptions none;
  none.bridge_max_jump = 0;
  const int64_t sparse = LeftMedian(ball, shell, f, none)->Count();
  const int64_t filled = LeftMedian(ball, shell, f)->Count();
  EXPECT_GT(filled, sparse * 3 / 2);
  // Solid images stay solid: a ball moving toward a torus and a box.
  const VoxelSet torus = *TorusSet(f, {0, 0, 0.4}, {0, 0, 1}, 0.55, 0.15);
  const VoxelSet far_ball = *SphereSet(f, {-0.5, -0.5, -0.5}, 0.35);
  const VoxelSet box = *BoxSet(f, {{0.2, 0.3, 0.1}, {0.8, 0.7, 0.6}});
  // Halving the distance to a convex set is one-to-one, so solids moving
  // toward one keep their topology: no pockets may appear.
  EXPECT_EQ(EnclosedEmptyVoxels(*LeftMedian(far_ball, box, f)), 0);
  EXPECT_EQ(EnclosedEmptyVoxels(*LeftMedian(torus, far_ball, f)), 0);
  EXPECT_EQ(EnclosedEmptyVoxels(*LeftMedian(CowAt48(), far_ball, f)), 0);
}

TEST(Median, CubeImageFillMatchesPerTetrahedronTests) {
  // The gap filling's one-pass fill of a cube's image against a voxel-by-
  // voxel test of each tetrahedron: stretched, folded, flat and clipped
  // corner images, into sets that already hold some of the voxels.
  Rng rng(77, 0);
  const Int3 res{70, 40, 40};
  for (int trial = 0; trial < 400; ++trial) {
    const Int3 at{int(rng.Next() % 60) - 2, int(rng.Next() % 30), int(rng.Next() % 30)};
    const int spread = 1 + trial % 6;
    Int3 img[8];
    for (int c = 0; c < 8; ++c) {
      auto jitter = [&] { return int(rng.Next() % (2 * spread + 1)) - spread; };
      img[c] = {at.x + 2 * (c & 1) + jitter(), at.y + 2 * ((c >> 1) & 1) + jitter(),
                at.z + 2 * (c >> 2) + jitter()};
      if (trial % 10 == 0) img[c].z = at.z;  // flat: no tetrahedron has volume
      // Images sharing coordinates put voxels on the sides of their box
      // inside the hull too (what the fill's hull filter must keep).
      if (trial % 10 == 3)
        img[c] = {at.x + spread * (c & 1), at.y + 2 * ((c >> 1) & 1), at.z + 2 * (c >> 2)};
      if (trial % 10 == 5) img[c].x = at.x + spread * (c & 1);
      if (trial % 10 == 7) img[c] = {at.x + 3 * (c & 1), at.y + 3 * ((c >> 1) & 1), img[c].z};
    }
    const VoxelBox box = CubeImageBox(img, res);
    VoxelSet before = RandomSet(res, trial % 3 == 0 ? 0.0 : 0.3, rng);
    VoxelSet got = before;
    FillCubeImage(img, box, got);
    const VoxelSet want = before | testing::BruteForceCubeImage(img, box, res);
    ASSERT_EQ(got, want) << "trial " << trial;
    if (trial % 10 == 0) {
      EXPECT_EQ(got, before) << "trial " << trial;
    }
    bool full = true;
    for (int z = box.min.z; z <= box.max.z; ++z)
      for (int y = box.min.y; y <= box.max.y; ++y)
        for (int x = box.min.x; x <= box.max.x; ++x) full = full && want.Get(x, y, z);
    EXPECT_EQ(BoxFilled(got, box), full) << "trial " << trial;
    // The deferred check: asked once when the fill would add a voxel,
    // never otherwise; a "no" adds nothing.
    int asked = 0;
    VoxelSet refused = before;
    FillCubeImage(img, box, refused, [&] { return ++asked, false; });
    EXPECT_EQ(refused, before) << "trial " << trial;
    EXPECT_EQ(asked, want == before ? 0 : 1) << "trial " << trial;
    asked = 0;
    VoxelSet again = got;
    FillCubeImage(img, box, again, [&] { return ++asked, true; });
    EXPECT_EQ(again, got) << "trial " << trial;
    EXPECT_EQ(asked, 0) << "trial " << trial;
  }
}

TEST(Median, RejectsBadInput) {
  const GridFrame f = Cube(16);
  const VoxelSet empty(f.resolution);
  const VoxelSet ball = *SphereSet(f, {0, 0, 0}, 0.5);
  EXPECT_FALSE(Median(empty, ball, f).ok());
  EXPECT_FALSE(MakeMedianMap(f, empty).ok());
  EXPECT_FALSE(MakeMedianMap(Cube(17), ball).ok());
  RotatedMedianOptions ro;
  ro.axis = {0, 0, 0};
  EXPECT_FALSE(MakeRotatedMedianMap(f, ball, ro).ok());
}

// ---------------------------------------------------------------- other maps

TEST(SetMaps, ConstantMapReturnsItsSet) {
  const GridFrame f = Cube(16);
  const VoxelSet ball = *SphereSet(f, {0, 0, 0}, 0.5);
  SetMapWorkspace ws;
  VoxelSet out;
  ASSERT_TRUE((*MakeConstantMap(f, ball))->Apply(*BoxSet(f, {{0, 0, 0}, {1, 1, 1}}), out, ws).ok());
  EXPECT_EQ(out, ball);
}

TEST(SetMaps, AffinePointMapsKeepSolidsSolid) {
  const GridFrame f = Cube(48);
  const VoxelSet box = *BoxSet(f, {{-0.5, -0.25, -0.25}, {0.5, 0.25, 0.25}});
  // A rotation is an isometry: same volume, no pinholes.
  const VoxelSet turned = TransformSet(box, f, Affine3::Rotate({1, 1, 0}, 33));
  EXPECT_NEAR(double(turned.Count()) / box.Count(), 1.0, 0.05);
  EXPECT_EQ(EnclosedEmptyVoxels(turned), 0);
  // Halving shrinks the volume eightfold.
  PointMap half;
  half.pre = Affine3::Scale({0.5, 0.5, 0.5});
  SetMapWorkspace ws;
  VoxelSet out;
  ASSERT_TRUE((*MakePointSetMap(f, half))->Apply(box, out, ws).ok());
  EXPECT_NEAR(double(out.Count()) / box.Count(), 0.125, 0.03);
  // Doubling (an expansion) leaves no holes.
  PointMap twice;
  twice.pre = Affine3::Scale({2, 2, 2});
  ASSERT_TRUE((*MakePointSetMap(f, twice))->Apply(*SphereSet(f, {0, 0, 0}, 0.3), out, ws).ok());
  EXPECT_EQ(EnclosedEmptyVoxels(out), 0);
  EXPECT_NEAR(out.Count() * std::pow(2.0 / 48, 3), 4.0 / 3 * M_PI * 0.216, 0.05);
}

TEST(SetMaps, NonlinearPointMapIsSeededAndSubdividesStretches) {
  // The reference description's polar doubling: angles double, radii shrink by sqrt 2.
  const GridFrame f = Cube(48);
  PointMap polar;
  polar.variations.push_back({VariationKind::kPolarDoubling, 1.0, {}});
  const SetMapPtr map = *MakePointSetMap(f, polar);
  const VoxelSet ring = *TorusSet(f, {0, 0, 0}, {0, 0, 1}, 0.6, 0.12);
  SetMapWorkspace ws;
  ws.seed = 3;
  VoxelSet out;
  ASSERT_TRUE(map->Apply(ring, out, ws).ok());
  // A ring of radius 0.6 goes to a ring of radius 0.6 / sqrt 2, covered all
  // round although each angle doubles.
  const double s2 = std::sqrt(2.0), h = f.VoxelSize().x;
  const VoxelSet expected = *TorusSet(f, {0, 0, 0}, {0, 0, 1}, 0.6 / s2, 0.12 / s2);
  const VoxelSet loose = *TorusSet(f, {0, 0, 0}, {0, 0, 1}, 0.6 / s2, 0.12 / s2 + 1.5 * h);
  EXPECT_GT((out & expected).Count(), expected.Count() * 9 / 10);
  EXPECT_LT((out - loose).Count(), out.Count() / 50);
  // A map with random variations is reproducible for a seed.
  PointMap blur;
  blur.pre = Affine3::Scale({0.3, 0.3, 0.3});
  blur.variations.push_back({VariationKind::kBlur, 0.2, {}});
  const SetMapPtr blurry = *MakePointSetMap(f, blur);
  VoxelSet b1, b2;
  ASSERT_TRUE(blurry->Apply(ring, b1, ws).ok());
  ASSERT_TRUE(blurry->Apply(ring, b2, ws).ok());
  EXPECT_EQ(b1, b2);
}

}  // namespace
}  // namespace nimbus
