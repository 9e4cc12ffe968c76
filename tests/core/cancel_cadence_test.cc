// Every long set computation polls its interrupter often enough to stop
// within ~10 ms of work, and stops when told. Poll counts are exact
// measures of the cadence; bench/cancel_latency_bench.cc prints the times.
#include <gtest/gtest.h>

#include <atomic>

#include "core/sets/feature_transform.h"
#include "core/sets/set_ifs.h"
#include "core/sets/set_maps.h"
#include "core/sets/shapes.h"
#include "core/sets/voxelize.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

GridFrame Cube(int n) { return {{n, n, n}, {{-1, -1, -1}, {1, 1, 1}}}; }

// Counts polls and says "stop" from poll `stop_at` on (0 = never).
class CountingInterrupter final : public Interrupter {
 public:
  explicit CountingInterrupter(uint64_t stop_at = 0) : stop_at_(stop_at) {}
  bool WasInterrupted(uint64_t, uint64_t) override {
    const uint64_t n = ++polls_;
    return stop_at_ != 0 && n >= stop_at_;
  }
  uint64_t polls() const { return polls_; }

 private:
  uint64_t stop_at_;
  std::atomic<uint64_t> polls_{0};
};

TEST(CancelCadence, FeatureTransformPollsOncePerSliceOfEachPass) {
  const GridFrame f = Cube(64);
  const VoxelSet sphere = *SphereSet(f, {0, 0, 0}, 0.4);
  CountingInterrupter count;
  ASSERT_TRUE(ComputeFeatureTransform(sphere, f.VoxelSize(), &count).ok());
  EXPECT_EQ(count.polls(), 3u * 64);  // x, y and z passes: one poll per slice or layer

  CountingInterrupter stop(10);
  const absl::StatusOr<FeatureField> cut = ComputeFeatureTransform(sphere, f.VoxelSize(), &stop);
  EXPECT_EQ(cut.status().code(), absl::StatusCode::kCancelled);
  EXPECT_LT(stop.polls(), 64u);  // stopped within the first pass
}

TEST(CancelCadence, MedianAndMedianMapStopWhenTold) {
  const GridFrame f = Cube(48);
  const VoxelSet a = *SphereSet(f, {-0.3, 0, 0}, 0.3);
  const VoxelSet b = *BoxSet(f, {{0.1, -0.2, -0.2}, {0.6, 0.3, 0.2}});
  CountingInterrupter count;
  ASSERT_TRUE(Median(a, b, f, {}, &count).ok());
  // Two feature transforms on the sets' bounding boxes (a few tens of
  // slices each), polled per slice.
  EXPECT_GE(count.polls(), 2u * 48);

  CountingInterrupter stop(5);
  EXPECT_EQ(Median(a, b, f, {}, &stop).status().code(), absl::StatusCode::kCancelled);
  CountingInterrupter stop_map(5);
  EXPECT_EQ(MakeMedianMap(f, a, {}, &stop_map).status().code(), absl::StatusCode::kCancelled);
}

TEST(CancelCadence, SetIfsPollsWithinEveryIteration) {
  const GridFrame f = Cube(32);
  const SetIfs ifs{f,
                   {*MakeMedianMap(f, *SphereSet(f, {-0.4, 0, 0}, 0.3)),
                    *MakeMedianMap(f, *BoxSet(f, {{0.2, -0.3, -0.3}, {0.7, 0.3, 0.3}}))},
                   {},
                   {}};
  SetIfsRunOptions o;
  o.iterations = 6;
  o.warmup = 2;
  CountGrid counts(f.resolution);
  CountingInterrupter count;
  ASSERT_TRUE(RunSetIfs(ifs, o, counts, &count).ok());
  // Each iteration's median runs feature transforms polling per slice.
  EXPECT_GE(count.polls(), 8u * 32);

  CountGrid cut_counts(f.resolution);
  CountingInterrupter stop(40);
  EXPECT_EQ(RunSetIfs(ifs, o, cut_counts, &stop).status().code(), absl::StatusCode::kCancelled);
}

TEST(CancelCadence, MeshVoxelisationStopsWhenTold) {
  VoxelizeOptions fit;
  fit.fit = true;
  for (const char* mesh : {"examples/meshes/cow.obj", "examples/meshes/suzanne.obj"}) {
    CountingInterrupter stop(2);
    const absl::StatusOr<VoxelizeResult> r =
        LoadAndVoxelize(testing::SourcePath(mesh), Cube(64), fit, &stop);
    EXPECT_EQ(r.status().code(), absl::StatusCode::kCancelled) << mesh;
  }
}

}  // namespace
}  // namespace nimbus
