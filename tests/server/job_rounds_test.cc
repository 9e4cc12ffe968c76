// JobDriver::RunRounds: round targets follow the time per round, rounded
// to the step multiple a chaos game asks for (whole chunks per thread).
#include <gtest/gtest.h>

#include <chrono>
#include <thread>
#include <vector>

#include "server/job_driver.h"
#include "tests/support/fake_job_context.h"

namespace nimbus::server {
namespace {

// Rounds over an engine that takes `ms[i]` milliseconds for round i and
// does exactly what it is asked (up to the total); the targets asked for.
std::vector<uint64_t> Targets(uint64_t total, uint64_t multiple, const std::vector<int>& ms) {
  JobPlan plan;
  testing::FakeJobContext ctx;
  JobDriver d(plan, ctx);
  EXPECT_TRUE(d.BeginPhase(JobPhase::kIterating, total, "iterations").ok());
  std::vector<uint64_t> targets;
  uint64_t done = 0;
  JobDriver::Rounds r;
  r.total = total;
  r.min_step = 4;
  r.first_step = multiple;
  r.step_multiple = multiple;
  r.advance = [&](uint64_t target) -> absl::StatusOr<uint64_t> {
    targets.push_back(target);
    const size_t i = targets.size() - 1;
    std::this_thread::sleep_for(std::chrono::milliseconds(ms[i % ms.size()]));
    done = std::min(target, total);
    return done;
  };
  r.finished = [&] { return done >= total; };
  EXPECT_TRUE(d.RunRounds(r).ok());
  return targets;
}

TEST(JobRounds, StepsAreWholeMultiplesForEveryThread) {
  // Round times that would give steps of no particular size.
  const std::vector<uint64_t> targets = Targets(1000003, 8, {3, 7, 5, 11, 2});
  ASSERT_GE(targets.size(), 3u);
  uint64_t before = 0;
  for (size_t i = 0; i + 1 < targets.size(); ++i) {
    EXPECT_EQ((targets[i] - before) % 8, 0u) << "round " << i << ": " << before << " -> "
                                              << targets[i];
    before = targets[i];
  }
  EXPECT_GE(targets.back(), 1000003u);
}

TEST(JobRounds, WithoutAMultipleStepsFollowTheRoundTimeAlone) {
  const std::vector<uint64_t> targets = Targets(1000003, 0, {3, 7, 5, 11, 2});
  ASSERT_GE(targets.size(), 3u);
  bool some_odd = false;
  uint64_t before = 0;
  for (size_t i = 0; i + 1 < targets.size(); ++i) {
    some_odd = some_odd || (targets[i] - before) % 8 != 0;
    before = targets[i];
  }
  EXPECT_TRUE(some_odd);
}

}  // namespace
}  // namespace nimbus::server
