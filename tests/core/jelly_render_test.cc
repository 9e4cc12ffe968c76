// Jelly frames: VRR leaves (count N^depth, order by address), chaos-game
// leaves that correspond between frames, bitwise reproducibility for any
// thread count, no leaf below the ground, and the velocity grid "v"
// against finite differences of leaf positions, through a real VDB file.
#include <gtest/gtest.h>

#include <tbb/task_arena.h>

#include <algorithm>
#include <cmath>
#include <cstring>

#include "core/io/vdb_io.h"
#include "core/jelly/jelly_frames.h"
#include "core/jelly/jelly_render.h"
#include "tests/support/jelly_oracles.h"
#include "tests/support/jelly_scenes.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

using testing::SierpinskiJelly;

GridFrame Frame(int res) { return {{res, res, res}, {{-1.2, 0, -1.2}, {1.2, 2.4, 1.2}}}; }

TEST(JellyRender, VrrLeafCountIsMapsToTheDepthTimesSeeds) {
  JellyPlan p = SierpinskiJelly(4);
  auto world = JellyWorld::Create(p.sim);
  ASSERT_TRUE(world.ok());
  for (uint32_t depth : {0u, 1u, 4u, 6u}) {
    p.render.depth = depth;
    p.render.start_points = {{0, 0, 0}, {0.1, 0.2, 0.3}};
    std::vector<Vec3> leaves;
    ASSERT_TRUE(JellyLeaves(world->Maps(), p.render, leaves, nullptr).ok());
    EXPECT_EQ(leaves.size(), uint64_t(std::pow(4, depth)) * 2);
    EXPECT_EQ(VrrLeafCount(4, depth, 2), leaves.size());
  }
  EXPECT_EQ(VrrLeafCount(4, 4, 1), 256u);
  EXPECT_EQ(VrrLeafCount(1000, 10, 1), UINT64_MAX);
}

TEST(JellyRender, VrrLeavesAreTheCompositionsInAddressOrder) {
  JellyPlan p = SierpinskiJelly(5);
  p.render.start_points = {{0.1, 0.2, 0.3}, {-0.4, 0, 0.2}, {0, 1, 0}};
  auto world = JellyWorld::Create(p.sim);
  ASSERT_TRUE(world.ok());
  for (int i = 0; i < 40; ++i) world->Step();
  const std::vector<Affine3> maps = world->Maps();
  std::vector<Vec3> leaves;
  ASSERT_TRUE(JellyLeaves(maps, p.render, leaves, nullptr).ok());
  for (uint64_t k = 0; k < leaves.size(); k += 7) {
    const Vec3 want = testing::VrrLeafByAddress(maps, 5, p.render.start_points, k);
    ASSERT_LT(Length(leaves[k] - want), 1e-12) << k;
  }
}

// Every frame's leaves of a 1-second run under `threads` threads.
std::vector<std::vector<Vec3>> RunFrames(JellyPlan p, int threads) {
  std::vector<std::vector<Vec3>> frames;
  tbb::task_arena arena(threads);
  arena.execute([&] {
    auto world = JellyWorld::Create(p.sim);
    for (uint64_t f = 0; f < p.frames; ++f) {
      if (f > 0) {
        EXPECT_TRUE(AdvanceFrame(*world, p, f, {}, nullptr).ok());
      }
      std::vector<Vec3> leaves;
      EXPECT_TRUE(FrameLeaves(*world, p, leaves, nullptr).ok());
      frames.push_back(std::move(leaves));
    }
  });
  return frames;
}

TEST(JellyRender, SameSpecSameLeavesBitwiseForAnyThreadCount) {
  for (JellyRenderMode mode : {JellyRenderMode::kVrr, JellyRenderMode::kChaosGame}) {
    JellyPlan p = SierpinskiJelly(8);  // 65536 leaves: several chunks
    p.frames = 12;
    p.render.mode = mode;
    p.render.points = 100000;
    p.render.seed = 5;
    const auto one = RunFrames(p, 1);
    const auto four = RunFrames(p, 4);
    ASSERT_EQ(one.size(), four.size());
    for (size_t f = 0; f < one.size(); ++f) {
      ASSERT_EQ(one[f].size(), four[f].size());
      ASSERT_EQ(0, std::memcmp(one[f].data(), four[f].data(), one[f].size() * sizeof(Vec3)))
          << "frame " << f;
    }
    // And the jelly moved.
    EXPECT_NE(0, std::memcmp(one[0].data(), one[11].data(), one[0].size() * sizeof(Vec3)));
  }
}

TEST(JellyRender, NoLeafEndsBelowTheGround) {
  JellyPlan p = SierpinskiJelly(6);
  // Resting bodies hold the lowest leaves at about twice their height:
  // a ground below zero is where leaves would fall through.
  p.sim.ground.height = -0.5;
  p.frames = 48;
  auto world = JellyWorld::Create(p.sim);
  ASSERT_TRUE(world.ok());
  uint64_t moved = 0;
  for (uint64_t f = 0; f < p.frames; ++f) {
    if (f > 0) {
      ASSERT_TRUE(AdvanceFrame(*world, p, f, {}, nullptr).ok());
    }
    std::vector<Vec3> leaves;
    auto clamped = FrameLeaves(*world, p, leaves, nullptr);
    ASSERT_TRUE(clamped.ok());
    moved += *clamped;
    for (const Vec3& q : leaves) ASSERT_GE(q.y, -0.5) << "frame " << f;
  }
  EXPECT_GT(moved, 0u);  // the scene does reach the ground
}

TEST(JellyRender, VelocityGridIsTheMeanFiniteDifferenceOfItsLeaves) {
  for (JellyRenderMode mode : {JellyRenderMode::kVrr, JellyRenderMode::kChaosGame}) {
    JellyPlan p = SierpinskiJelly(6);
    p.render.mode = mode;
    p.render.points = 20000;
    auto world = JellyWorld::Create(p.sim);
    ASSERT_TRUE(world.ok());
    std::vector<Vec3> prev, leaves;
    for (uint64_t f = 1; f <= 6; ++f) ASSERT_TRUE(AdvanceFrame(*world, p, f, {}, nullptr).ok());
    ASSERT_TRUE(FrameLeaves(*world, p, prev, nullptr).ok());
    ASSERT_TRUE(AdvanceFrame(*world, p, 7, {}, nullptr).ok());
    ASSERT_TRUE(FrameLeaves(*world, p, leaves, nullptr).ok());
    const GridFrame frame = Frame(64);
    auto acc = AccumulateLeaves(leaves, prev, 1 / p.fps, frame, true);
    ASSERT_TRUE(acc.ok());
    const JellyFrameGrids& g = *acc;
    const auto want = testing::MeanLeafVelocity(leaves, prev, 1 / p.fps, frame);
    ASSERT_EQ(g.velocity.voxels.size(), want.size());
    // Falling: leaves move down at about g·t.
    double mean_vy = 0;
    for (const auto& [c, v] : g.velocity.voxels) {
      const Vec3 w = want.at({c.x, c.y, c.z});
      ASSERT_LT(Length(v - w), 1e-9 * (1 + Length(w)));
      mean_vy += v.y / double(want.size());
    }
    EXPECT_LT(mean_vy, -1.0);
    // Through a real file: float precision.
    testing::TempDir dir;
    ASSERT_TRUE(WriteDensityVdb(dir / "f.vdb", g.counts, frame, {}, {}, {g.velocity}).ok());
    auto back = ReadVec3VdbFile(dir / "f.vdb", "v");
    ASSERT_TRUE(back.ok()) << back.status();
    size_t active = 0;
    for (const auto& [key, w] : want) {
      const auto [x, y, z] = key;
      ASSERT_TRUE(back->active[(size_t(x) * 64 + y) * 64 + z]);
      EXPECT_LT(Length(back->At(x, y, z) - w), 1e-5 * (1 + Length(w)));
      ++active;
    }
    EXPECT_EQ(active, std::count(back->active.begin(), back->active.end(), true));
  }
}

TEST(JellyRender, FirstFrameHasZeroVelocity) {
  const std::vector<Vec3> leaves{{0.1, 0.5, 0.1}, {0.5, 0.5, 0.5}};
  auto acc = AccumulateLeaves(leaves, {}, 1 / 24.0, Frame(16), true);
  ASSERT_TRUE(acc.ok());
  const JellyFrameGrids& g = *acc;
  ASSERT_EQ(g.velocity.voxels.size(), 2u);
  for (const auto& [c, v] : g.velocity.voxels) EXPECT_EQ(v, Vec3{});
  EXPECT_EQ(g.counts.Total(), 2u);
}

TEST(JellyRender, InterruptedRenderIsCancelled) {
  struct Always : Interrupter {
    bool WasInterrupted(uint64_t, uint64_t) override { return true; }
  } stop;
  JellyPlan p = SierpinskiJelly(8);
  auto world = JellyWorld::Create(p.sim);
  std::vector<Vec3> leaves;
  EXPECT_TRUE(absl::IsCancelled(JellyLeaves(world->Maps(), p.render, leaves, &stop)));
  EXPECT_TRUE(absl::IsCancelled(AdvanceFrame(*world, p, 1, {}, &stop)));
  ASSERT_TRUE(JellyLeaves(world->Maps(), p.render, leaves, nullptr).ok());
  EXPECT_TRUE(absl::IsCancelled(
      AccumulateLeaves(leaves, {}, 1 / 24.0, Frame(16), true, &stop).status()));
}

}  // namespace
}  // namespace nimbus
