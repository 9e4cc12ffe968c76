#include "server/job_runner.h"

#include <variant>

namespace nimbus::server {

absl::Status RunJobPlan(const JobPlan& plan, JobContext& ctx) {
  // Overload resolution picks the kind's runner; a kind without one does
  // not compile.
  return std::visit([&](const auto& kind) { return RunKind(plan, kind, ctx); }, plan.kind);
}

}  // namespace nimbus::server
