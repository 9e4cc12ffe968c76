#include "tests/support/claim_order_oracle.h"

#include <algorithm>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"

namespace nimbus::testing {
namespace {

// Jobs of `owner` claimed before `t` and not ended by then.
int RunningAt(const std::vector<ClaimedJob>& jobs, const std::string& owner, int64_t t) {
  int n = 0;
  for (const ClaimedJob& j : jobs) n += j.owner == owner && j.claim_ms < t && j.end_ms > t;
  return n;
}

// When `job` heads its owner's queue at its priority: visible, and the
// owner's previous job of that priority (by submission) claimed.
int64_t HeadSince(const std::vector<ClaimedJob>& jobs, const ClaimedJob& job) {
  int64_t since = job.visible_ms;
  const ClaimedJob* previous = nullptr;
  for (const ClaimedJob& j : jobs)
    if (j.owner == job.owner && j.priority == job.priority && j.visible_ms < job.visible_ms &&
        (previous == nullptr || j.visible_ms > previous->visible_ms))
      previous = &j;
  if (previous != nullptr) since = std::max(since, previous->claim_ms);
  return since;
}

}  // namespace

std::vector<std::string> PriorityViolations(const std::vector<ClaimedJob>& jobs, int slots) {
  std::vector<std::string> out;
  for (const ClaimedJob& h : jobs) {
    std::vector<std::string> passed;
    for (const ClaimedJob& l : jobs)
      if (l.priority < h.priority && l.claim_ms > h.visible_ms && l.claim_ms < h.claim_ms)
        passed.push_back(absl::StrCat(l.id, "@", l.claim_ms));
    if (static_cast<int>(passed.size()) > slots - 1)
      out.push_back(absl::StrCat("priority ", h.priority, " job ", h.id, " (visible at ",
                                 h.visible_ms, ", claimed at ", h.claim_ms, ") waited while ",
                                 passed.size(),
                                 " lower ones were claimed: ", absl::StrJoin(passed, " ")));
  }
  return out;
}

std::vector<std::string> FairShareViolations(const std::vector<ClaimedJob>& jobs, int slots) {
  std::vector<std::string> out;
  for (const ClaimedJob& j : jobs) {
    const int64_t since = HeadSince(jobs, j);
    std::vector<std::string> ahead;
    for (const ClaimedJob& x : jobs) {
      if (x.owner == j.owner || x.priority != j.priority) continue;
      if (x.claim_ms <= since || x.claim_ms >= j.claim_ms) continue;
      // The rule serves the owner with fewer jobs running first.
      if (RunningAt(jobs, x.owner, x.claim_ms) < RunningAt(jobs, j.owner, x.claim_ms)) continue;
      ahead.push_back(absl::StrCat(x.id, "@", x.claim_ms));
    }
    if (static_cast<int>(ahead.size()) > 2 + (slots - 1))
      out.push_back(absl::StrCat(j.owner, "'s priority ", j.priority, " job ", j.id,
                                 " (heading its queue at ", since, ", claimed at ", j.claim_ms,
                                 ") waited while ", ahead.size(),
                                 " of other owners were claimed: ", absl::StrJoin(ahead, " ")));
  }
  return out;
}

}  // namespace nimbus::testing
