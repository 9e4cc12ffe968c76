// A chaos game deep in its warm-up still stops when asked: the interrupter
// is polled inside chunks, warm-up and re-seeds included, on the fast
// (affine) and the slow (nonlinear) path.
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <future>

#include "core/chaos/chaos_game.h"

namespace nimbus {
namespace {

// Interrupts from its first poll on, and counts the polls.
class StopAtOnce : public Interrupter {
 public:
  bool WasInterrupted(uint64_t, uint64_t) override {
    ++polls;
    return true;
  }
  std::atomic<int> polls{0};
};

// The Sierpinski tetrahedron with a warm-up of four billion steps per
// walker: one chunk's warm-up alone is 6.4·10¹⁰ steps, minutes of work.
ChaosGameParams EndlessWarmup(bool nonlinear) {
  ChaosGameParams p;
  const Vec3 corners[4] = {
      {0.5, 0.5, 0.5}, {0.5, -0.5, -0.5}, {-0.5, 0.5, -0.5}, {-0.5, -0.5, 0.5}};
  for (const Vec3& c : corners) {
    PointMap m;
    m.pre = Affine3::Translate(c) * Affine3::Scale({0.5, 0.5, 0.5});
    if (nonlinear) m.variations.push_back({VariationKind::kSinusoidal, 0.5, {}});
    p.ifs.maps.push_back(m);
  }
  p.ifs.probabilities = {0.25, 0.25, 0.25, 0.25};
  p.frame.resolution = {32, 32, 32};
  p.frame.bounds = {{-1, -1, -1}, {1, 1, 1}};
  p.iterations = ChaosGame::kChunkIterations * 8;
  p.warmup = 4'000'000'000u;
  p.seed = 3;
  return p;
}

void ExpectPromptCancel(bool nonlinear) {
  auto game = ChaosGame::Create(EndlessWarmup(nonlinear), 2);
  ASSERT_TRUE(game.ok()) << game.status();
  EXPECT_EQ(ChaosGame::UsesFastPath((*game)->params()), !nonlinear);
  StopAtOnce stop;
  auto run = std::async(std::launch::async, [&] { return (*game)->Run(&stop); });
  // A guard against hanging, not a speed claim: unpolled, this warm-up
  // runs for minutes.
  ASSERT_EQ(run.wait_for(std::chrono::minutes(2)), std::future_status::ready)
      << "the warm-up never polled the interrupter";
  const absl::Status st = run.get();
  EXPECT_EQ(st.code(), absl::StatusCode::kCancelled) << st;
  EXPECT_GE(stop.polls.load(), 1);
  EXPECT_FALSE((*game)->done());
}

TEST(ChaosWarmupCancel, FastPathStopsInsideWarmup) { ExpectPromptCancel(false); }

TEST(ChaosWarmupCancel, SlowPathStopsInsideWarmup) { ExpectPromptCancel(true); }

}  // namespace
}  // namespace nimbus
