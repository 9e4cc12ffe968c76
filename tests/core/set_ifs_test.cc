#include "core/sets/set_ifs.h"

#include <gtest/gtest.h>

#include <algorithm>

#include "core/sets/feature_transform.h"
#include "core/sets/shapes.h"
#include "core/sets/voxelize.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

GridFrame Cube(int n) { return {{n, n, n}, {{-1, -1, -1}, {1, 1, 1}}}; }

std::vector<uint32_t> Dense(const CountGrid& counts) {
  const Int3 r = counts.resolution();
  std::vector<uint32_t> out;
  for (int z = 0; z < r.z; ++z)
    for (int y = 0; y < r.y; ++y)
      for (int x = 0; x < r.x; ++x) out.push_back(counts.Get(x, y, z));
  return out;
}

SetIfs TwoShapes(int n) {
  const GridFrame f = Cube(n);
  const VoxelSet a = *SphereSet(f, {-0.5, -0.4, 0}, 0.3);
  const VoxelSet b = *BoxSet(f, {{0.3, 0.1, -0.3}, {0.8, 0.6, 0.3}});
  return {f, {*MakeMedianMap(f, a), *MakeMedianMap(f, b)}, {}, {}};
}

TEST(SetIfs, RandomIterationIsDeterministicAndCountsEverySet) {
  const SetIfs ifs = TwoShapes(32);
  SetIfsRunOptions o;
  o.iterations = 60;
  o.warmup = 8;
  o.seed = 4;
  CountGrid c1(ifs.frame.resolution), c2(ifs.frame.resolution), c3(ifs.frame.resolution);
  const absl::StatusOr<SetIfsRunStats> s1 = RunSetIfs(ifs, o, c1);
  ASSERT_TRUE(s1.ok()) << s1.status();
  ASSERT_TRUE(RunSetIfs(ifs, o, c2).ok());
  EXPECT_EQ(Dense(c1), Dense(c2));
  o.seed = 5;
  ASSERT_TRUE(RunSetIfs(ifs, o, c3).ok());
  EXPECT_NE(Dense(c1), Dense(c3));
  EXPECT_EQ(s1->iterations, 68u);
  EXPECT_EQ(s1->map_uses[0] + s1->map_uses[1], 68u);
  EXPECT_EQ(c1.Total(), s1->voxels_counted);
  EXPECT_LE(c1.Max(), 60u);
}

TEST(SetIfs, CountsEveryMemberOfEverySetAtAnyResolution) {
  // Counting works a 64-bit word and a 32-voxel tile at a time: a lattice
  // whose sides are multiples of neither, and sets reaching its far sides,
  // against one increment per member of every counted set.
  const GridFrame f{{100, 45, 37}, {{-1, -1, -1}, {1, 1, 1}}};
  const VoxelSet a = *SphereSet(f, {0.5, 0.4, 0.3}, 0.6);
  const VoxelSet b = *BoxSet(f, {{-1, -1, -1}, {-0.2, 0.1, 0.2}});
  const SetIfs ifs{f, {*MakeMedianMap(f, a), *MakeMedianMap(f, b)}, {}, {}};
  SetIfsRunOptions o;
  o.iterations = 12;
  o.warmup = 2;
  o.observe_every = 1;
  std::vector<uint32_t> want(size_t(f.resolution.Volume()), 0);
  o.observer = [&](uint64_t, const CountGrid&, const VoxelSet& set) {
    set.ForEach([&](int x, int y, int z) {
      ++want[(size_t(z) * f.resolution.y + size_t(y)) * f.resolution.x + size_t(x)];
    });
  };
  CountGrid counts(f.resolution);
  ASSERT_TRUE(RunSetIfs(ifs, o, counts).ok());
  EXPECT_EQ(Dense(counts), want);
}

TEST(SetIfs, CloudIsDensestInsideEverySketch) {
  // The reference description's bull, with the cow: sketch A is the cow, sketch B random
  // balls inside it; p = 2/3 and 1/3.
  const GridFrame f = Cube(64);
  VoxelizeOptions vo;
  vo.fit = true;
  const VoxelSet cow =
      LoadAndVoxelize(testing::SourcePath("examples/meshes/cow.obj"), f, vo)->interior;
  RandomBallsOptions bo;
  bo.count = 20;
  bo.min_radius = 0.05;
  bo.max_radius = 0.12;
  bo.seed = 3;
  const VoxelSet balls = *RandomBallsInside(cow, f, bo);
  SetIfs ifs{f, {*MakeMedianMap(f, cow), *MakeMedianMap(f, balls)}, {2.0 / 3, 1.0 / 3}, {}};
  CountGrid counts(f.resolution);
  SetIfsRunOptions o;
  o.iterations = 120;
  o.seed = 9;
  const absl::StatusOr<SetIfsRunStats> stats = RunSetIfs(ifs, o, counts);
  ASSERT_TRUE(stats.ok()) << stats.status();
  EXPECT_NEAR(double(stats->map_uses[0]) / stats->iterations, 2.0 / 3, 0.12);

  const VoxelSet both = cow & balls, cow_only = cow - balls;
  VoxelSet outside(f.resolution);
  outside.Fill();
  outside -= cow;
  outside -= balls;
  auto mean = [&](const VoxelSet& s) {
    double sum = 0;
    s.ForEach([&](int x, int y, int z) { sum += counts.Get(x, y, z); });
    return sum / double(s.Count());
  };
  const double in_both = mean(both), in_cow = mean(cow_only), out = mean(outside);
  EXPECT_GT(in_both, 1.3 * in_cow);
  EXPECT_GT(in_cow, 20 * out);
  // Voxels in both sketches are in (nearly) every counted set.
  EXPECT_GT(in_both, 0.9 * o.iterations);
  // The densest voxels all lie in both sketches.
  const uint32_t top = counts.Max();
  int64_t top_voxels = 0, top_in_both = 0;
  for (int z = 0; z < 64; ++z)
    for (int y = 0; y < 64; ++y)
      for (int x = 0; x < 64; ++x)
        if (counts.Get(x, y, z) == top) {
          ++top_voxels;
          top_in_both += both.Get(x, y, z);
        }
  EXPECT_EQ(top_in_both, top_voxels);
}

// Stops the run loop (which polls with the total iteration count) once it
// has done `after` iterations; inner polls from the maps pass through.
class StopAfter : public Interrupter {
 public:
  StopAfter(uint64_t total, uint64_t after) : total_(total), after_(after) {}
  bool WasInterrupted(uint64_t done, uint64_t total) override {
    ++polls;
    return total == total_ && done >= after_;
  }
  int polls = 0;

 private:
  uint64_t total_, after_;
};

TEST(SetIfs, ObserverAndInterrupter) {
  const SetIfs ifs = TwoShapes(24);
  SetIfsRunOptions o;
  o.iterations = 30;
  o.warmup = 4;
  o.observe_every = 10;
  std::vector<uint64_t> seen;
  o.observer = [&](uint64_t counted, const CountGrid& counts, const VoxelSet& current) {
    seen.push_back(counted);
    EXPECT_GT(counts.Total(), 0u);
    EXPECT_FALSE(current.Empty());
  };
  CountGrid counts(ifs.frame.resolution);
  ASSERT_TRUE(RunSetIfs(ifs, o, counts).ok());
  EXPECT_EQ(seen, (std::vector<uint64_t>{10, 20, 30}));

  StopAfter stop(34, 15);
  CountGrid partial(ifs.frame.resolution);
  const absl::StatusOr<SetIfsRunStats> r = RunSetIfs(ifs, o, partial, &stop);
  EXPECT_EQ(r.status().code(), absl::StatusCode::kCancelled);
  EXPECT_GT(partial.Total(), 0u);
  EXPECT_LT(partial.Total(), counts.Total());
  EXPECT_GT(stop.polls, 15);  // the maps poll too
}

TEST(SetIfs, RejectsInconsistentSystems) {
  const SetIfs good = TwoShapes(16);
  CountGrid counts(good.frame.resolution);
  SetIfs bad = good;
  bad.probabilities = {1.0};
  EXPECT_FALSE(RunSetIfs(bad, {}, counts).ok());
  bad = good;
  bad.probabilities = {-1, 2};
  EXPECT_FALSE(RunSetIfs(bad, {}, counts).ok());
  bad = good;
  bad.maps.push_back(*MakeConstantMap(Cube(8), *SphereSet(Cube(8), {0, 0, 0}, 0.5)));
  EXPECT_FALSE(ValidateSetIfs(bad).ok());
  CountGrid wrong({8, 8, 8});
  EXPECT_FALSE(RunSetIfs(good, {}, wrong).ok());
}

struct Page {
  uint64_t index;
  std::string address;
  VoxelSet set;
};

std::vector<Page> Book(const SetIfs& ifs, const BookOptions& o) {
  std::vector<Page> pages;
  const absl::Status s =
      RunBook(ifs, o, [&](uint64_t i, const std::string& address, const VoxelSet& set) {
        pages.push_back({i, address, set});
        return absl::OkStatus();
      });
  EXPECT_TRUE(s.ok()) << s;
  return pages;
}

TEST(SetIfsBook, PagesMorphFromAToB) {
  const SetIfs ifs = TwoShapes(32);
  const Vec3 h = ifs.frame.VoxelSize();
  const VoxelSet a = *SphereSet(ifs.frame, {-0.5, -0.4, 0}, 0.3);
  const VoxelSet b = *BoxSet(ifs.frame, {{0.3, 0.1, -0.3}, {0.8, 0.6, 0.3}});
  BookOptions o;
  o.depth = 5;
  const std::vector<Page> pages = Book(ifs, o);
  ASSERT_EQ(pages.size(), 32u);
  EXPECT_EQ(pages.front().address, "AAAAA");
  EXPECT_EQ(pages[1].address, "AAAAB");
  EXPECT_EQ(pages.back().address, "BBBBB");
  for (size_t i = 0; i < pages.size(); ++i) {
    EXPECT_EQ(pages[i].index, i);
    if (i > 0) {
      EXPECT_LT(pages[i - 1].address, pages[i].address);
    }
  }
  // Along the book the pages leave A and approach B; steps may wobble by a
  // couple of voxels.
  const double tolerance = 2.5 * h.x;
  double prev_a = -1, prev_b = 1e9;
  for (const Page& p : pages) {
    const double da = *HausdorffDistance(p.set, a, h), db = *HausdorffDistance(p.set, b, h);
    EXPECT_GE(da, prev_a - tolerance) << p.address;
    EXPECT_LE(db, prev_b + tolerance) << p.address;
    prev_a = std::max(prev_a, da);
    prev_b = std::min(prev_b, db);
  }
  const double span = *HausdorffDistance(a, b, h);
  EXPECT_LT(*HausdorffDistance(pages.front().set, a, h), 0.1 * span);
  EXPECT_LT(*HausdorffDistance(pages.back().set, b, h), 0.1 * span);
}

TEST(SetIfsBook, CacheDepthDoesNotChangePages) {
  const SetIfs ifs = TwoShapes(24);
  BookOptions roomy, tight;
  roomy.depth = tight.depth = 4;
  tight.cache_bytes = 0;  // recompute every composition per page
  const std::vector<Page> p1 = Book(ifs, roomy), p2 = Book(ifs, tight);
  ASSERT_EQ(p1.size(), p2.size());
  for (size_t i = 0; i < p1.size(); ++i) {
    EXPECT_EQ(p1[i].address, p2[i].address);
    EXPECT_EQ(p1[i].set, p2[i].set) << p1[i].address;
  }
}

TEST(SetIfsBook, BarnsleyCondensationWithThreeMaps) {
  // f_A = constant C, f_B = halving about a corner, f_C = median toward C.
  const GridFrame f = Cube(32);
  const VoxelSet c = *SphereSet(f, {0.4, 0.4, 0.4}, 0.35);
  PointMap half;
  half.pre = Affine3::Translate({-1, -1, -1}) * Affine3::Scale({0.5, 0.5, 0.5}) *
             Affine3::Translate({1, 1, 1});
  const SetIfs ifs{f,
                   {*MakeConstantMap(f, c), *MakePointSetMap(f, half), *MakeMedianMap(f, c)},
                   {},
                   {"A", "B", "C"}};
  BookOptions o;
  o.depth = 2;
  const std::vector<Page> pages = Book(ifs, o);
  ASSERT_EQ(pages.size(), 9u);
  EXPECT_EQ(pages[0].address, "AA");
  EXPECT_EQ(pages[5].address, "BC");
  EXPECT_EQ(pages[8].address, "CC");
  const VoxelSet halved = TransformSet(c, f, half.pre);
  for (const Page& p : pages) {
    if (p.address[0] == 'A') {
      EXPECT_EQ(p.set, c) << p.address;
    }
    if (p.address == "BA") {
      EXPECT_EQ(p.set, halved);
    }
    if (p.address == "CA") {
      EXPECT_EQ(p.set, c);  // M(C, C) = C
    }
  }
  EXPECT_FALSE(BookPageCount(3, 13).ok());
  EXPECT_EQ(*BookPageCount(3, 2), 9u);
  // A failing page callback stops the book with its status.
  int calls = 0;
  const absl::Status s = RunBook(ifs, o, [&](uint64_t, const std::string&, const VoxelSet&) {
    return ++calls == 2 ? absl::AbortedError("enough") : absl::OkStatus();
  });
  EXPECT_EQ(s.code(), absl::StatusCode::kAborted);
  EXPECT_EQ(calls, 2);
}

}  // namespace
}  // namespace nimbus
