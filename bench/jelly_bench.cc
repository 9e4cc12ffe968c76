// Elastic IFS figures for the reference description's scene (4 maps joined
// by 6 springs, VRR depth 4 = 256 leaves): physics steps per second, VRR
// frames per second with points as leaves (physics frame + leaves), and
// seconds per written VDB frame (density + velocity) at 128^3. The
// reference reports 780 frames/s for physics alone and 165 frames/s with
// rendering on a 1.8 GHz Athlon 64; the targets here are 100x and 10x.
#include <benchmark/benchmark.h>

#include <chrono>

#include "core/io/vdb_io.h"
#include "core/jelly/jelly_frames.h"
#include "core/jelly/jelly_render.h"
#include "tests/support/jelly_scenes.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

constexpr double kPhysicsReferenceFps = 780;
constexpr double kRenderReferenceFps = 165;

double Seconds(std::chrono::steady_clock::duration d) {
  return std::chrono::duration<double>(d).count();
}

void BM_JellyPhysicsSteps(benchmark::State& state) {
  const JellyPlan plan = testing::SierpinskiJelly(4);
  auto world = JellyWorld::Create(plan.sim);
  uint64_t steps = 0;
  for (auto _ : state) {
    world->Step();
    ++steps;
  }
  state.counters["steps_per_s"] = benchmark::Counter(double(steps), benchmark::Counter::kIsRate);
  benchmark::DoNotOptimize(world->state());
}
BENCHMARK(BM_JellyPhysicsSteps)->MinTime(0.5);

// One physics frame (10 substeps) plus its 256 VRR point leaves.
void BM_JellyVrrFrames(benchmark::State& state) {
  const JellyPlan plan = testing::SierpinskiJelly(uint32_t(state.range(0)));
  auto world = JellyWorld::Create(plan.sim);
  std::vector<Vec3> leaves;
  uint64_t frame = 1, frames = 0;
  const auto start = std::chrono::steady_clock::now();
  for (auto _ : state) {
    (void)AdvanceFrame(*world, plan, frame++, {}, nullptr);
    (void)FrameLeaves(*world, plan, leaves, nullptr);
    benchmark::DoNotOptimize(leaves.data());
    ++frames;
  }
  const double fps = double(frames) / Seconds(std::chrono::steady_clock::now() - start);
  state.counters["frames_per_s"] = fps;
  state.counters["leaves"] = double(leaves.size());
  if (state.range(0) == 4) state.counters["x_reference_165fps"] = fps / kRenderReferenceFps;
}
BENCHMARK(BM_JellyVrrFrames)->Arg(4)->Arg(7)->MinTime(0.5);

// Physics frames alone (10 substeps each), against the reference's 780.
void BM_JellyPhysicsFrames(benchmark::State& state) {
  const JellyPlan plan = testing::SierpinskiJelly(4);
  auto world = JellyWorld::Create(plan.sim);
  uint64_t frame = 1, frames = 0;
  const auto start = std::chrono::steady_clock::now();
  for (auto _ : state) {
    (void)AdvanceFrame(*world, plan, frame++, {}, nullptr);
    ++frames;
  }
  const double fps = double(frames) / Seconds(std::chrono::steady_clock::now() - start);
  state.counters["frames_per_s"] = fps;
  state.counters["x_reference_780fps"] = fps / kPhysicsReferenceFps;
}
BENCHMARK(BM_JellyPhysicsFrames)->MinTime(0.5);

// A whole written frame at 128^3: physics, leaves, counts and velocities,
// and the .vdb with density and v.
void BM_JellyVdbFrame(benchmark::State& state) {
  const JellyPlan plan = testing::SierpinskiJelly(uint32_t(state.range(0)));
  const GridFrame grid{{128, 128, 128}, {{-1.2, 0, -1.2}, {1.2, 2.4, 1.2}}};
  auto world = JellyWorld::Create(plan.sim);
  testing::TempDir dir;
  std::vector<Vec3> leaves, prev;
  uint64_t frame = 1, frames = 0;
  const auto start = std::chrono::steady_clock::now();
  for (auto _ : state) {
    (void)AdvanceFrame(*world, plan, frame++, {}, nullptr);
    (void)FrameLeaves(*world, plan, leaves, nullptr);
    auto g = AccumulateLeaves(leaves, prev, 1 / plan.fps, grid, true);
    (void)WriteDensityVdb(dir / "frame.vdb", g->counts, grid, {}, {}, {g->velocity});
    prev.swap(leaves);
    ++frames;
  }
  state.counters["s_per_frame"] =
      Seconds(std::chrono::steady_clock::now() - start) / double(frames);
}
BENCHMARK(BM_JellyVdbFrame)->Arg(4)->Arg(7)->Unit(benchmark::kMillisecond)->Iterations(20);

}  // namespace
}  // namespace nimbus

BENCHMARK_MAIN();
