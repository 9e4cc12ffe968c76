// An oracle of the claim order (docs/operator_guide.md "Claim order") for
// end-to-end tests whose claims race over several worker slots: it judges
// a finished run from what the test itself recorded (when each job was
// surely visible) and the store's claim and end stamps, with the slack that
// concurrent claims allow spelled out. It never asks the store for the
// order it should have followed.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace nimbus::testing {

/// One job of a run, with times in milliseconds of the system clock shared
/// by the test and the servers.
struct ClaimedJob {
  std::string id;
  std::string owner;
  int priority = 0;
  /// Read by the test just after SubmitJob returned: the job was committed
  /// QUEUED, so every claim stamped later could see it.
  int64_t visible_ms = 0;
  /// The stamp of its (first) claim: the `claimed` event's time, taken by
  /// the claiming worker before its claim transaction began.
  int64_t claim_ms = 0;
  /// When it ended (Job.end_time).
  int64_t end_ms = 0;
};

/// Priority: for each job H, the jobs of lower priority claimed while H
/// surely waited (stamped after H was visible and before H's claim). A
/// claimer that found every job of H's priority locked by other claimers
/// takes a lower one; each slot but H's own can do so once (its next claim
/// is stamped after H's was). So more than `slots - 1` such claims is a
/// violation, described in the returned lines (empty: none).
std::vector<std::string> PriorityViolations(const std::vector<ClaimedJob>& jobs, int slots);

/// Fair share: for each job J, from the time it heads its owner's queue at
/// its priority (visible, and its owner's older job of that priority
/// claimed) to its own claim, the claims of other owners' jobs of that
/// priority that the rule did not excuse: a claim is excused when its owner
/// had fewer jobs running (claimed and not ended, by the stamps) than J's
/// owner just before it. The rule allows two; claims racing with J's
/// owner's previous claim or with each other add at most `slots - 1`. More
/// is a violation, described in the returned lines (empty: none).
std::vector<std::string> FairShareViolations(const std::vector<ClaimedJob>& jobs, int slots);

}  // namespace nimbus::testing
