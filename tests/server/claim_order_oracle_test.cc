// The claim-order oracle (tests/support/claim_order_oracle.h) on runs
// written by hand, three slots: what it counts, what it excuses, and where
// its bounds lie.
#include "tests/support/claim_order_oracle.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <string>
#include <vector>

namespace nimbus::testing {
namespace {

using ::testing::ElementsAre;
using ::testing::HasSubstr;
using ::testing::IsEmpty;

constexpr int kSlots = 3;

ClaimedJob Job(const std::string& id, const std::string& owner, int priority, int64_t visible,
               int64_t claim, int64_t end) {
  return ClaimedJob{id, owner, priority, visible, claim, end};
}

// H is visible at 100 and claimed at 200: low claims at 100 and 200 are not
// inside that, those at 110 and 120 are (two: within 3 - 1).
TEST(ClaimOrderOracle, LowClaimsWhileAHighJobSurelyWaitedAreCountedUpToSlotsLessOne) {
  std::vector<ClaimedJob> run = {
      Job("h", "a", 90, 100, 200, 300), Job("l1", "b", 10, 0, 100, 400),
      Job("l2", "b", 10, 0, 110, 400),  Job("l3", "b", 10, 0, 120, 400),
      Job("l4", "b", 10, 0, 200, 400),
  };
  EXPECT_THAT(PriorityViolations(run, kSlots), IsEmpty());
  run.push_back(Job("l5", "a", 10, 0, 150, 400));  // a third
  EXPECT_THAT(PriorityViolations(run, kSlots),
              ElementsAre(AllOf(HasSubstr("job h "), HasSubstr("3 lower ones"),
                                HasSubstr("l2@110 l3@120 l5@150"))));
}

// b1 heads Bob's queue from 10 (visible; Bob has no older job) to its
// claim at 60. Alice's claims at 20..50 are four (2 + 3 - 1); a fifth is a
// violation. Alice had no fewer jobs running than Bob (0) at any of them.
TEST(ClaimOrderOracle, AnOwnerPassedOverMoreThanTwoPlusSlotsLessOneTimesIsReported) {
  std::vector<ClaimedJob> run = {Job("b1", "bob", 10, 10, 60, 1000)};
  for (int i = 0; i < 4; ++i)
    run.push_back(Job("a" + std::to_string(i), "alice", 10, i, 20 + 10 * i, 1000));
  EXPECT_THAT(FairShareViolations(run, kSlots), IsEmpty());
  run.push_back(Job("a4", "alice", 10, 4, 55, 1000));
  EXPECT_THAT(FairShareViolations(run, kSlots),
              ElementsAre(AllOf(HasSubstr("bob's priority 10 job b1"), HasSubstr("5 of other"))));
  // Claims at another priority are not counted against b1.
  run.back().priority = 90;
  EXPECT_THAT(FairShareViolations(run, kSlots), IsEmpty());
}

// Bob runs two jobs (claimed at 1 and 2, ending at 1000); b1 heads his
// queue from 2. Alice's six claims before b1's each end at once, so she
// has none running at each: fewer than Bob, the rule serves her first.
TEST(ClaimOrderOracle, ClaimsOfAnOwnerWithFewerJobsRunningAreExcused) {
  std::vector<ClaimedJob> run = {Job("b0", "bob", 10, 0, 1, 1000),
                                 Job("b00", "bob", 10, 1, 2, 1000),
                                 Job("b1", "bob", 10, 2, 100, 1000)};
  for (int i = 0; i < 6; ++i)
    run.push_back(Job("a" + std::to_string(i), "alice", 10, 0, 10 + 10 * i, 11 + 10 * i));
  EXPECT_THAT(FairShareViolations(run, kSlots), IsEmpty());
  // Alice's jobs run on: from her third claim she has two running, as many
  // as Bob, and her claims at 30..60 count (four, within 2 + 3 - 1) ...
  for (ClaimedJob& j : run)
    if (j.owner == "alice") j.end_ms = 1000;
  EXPECT_THAT(FairShareViolations(run, kSlots), IsEmpty());
  // ... a fifth, at 70, does not.
  run.push_back(Job("a6", "alice", 10, 0, 70, 1000));
  EXPECT_THAT(FairShareViolations(run, kSlots), ElementsAre(HasSubstr("job b1 ")));
}

}  // namespace
}  // namespace nimbus::testing
