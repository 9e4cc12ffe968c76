// Runs set-IFS jobs. Placeholder until condensation sets land.
#include "server/job_runner.h"

namespace nimbus::server {

absl::Status RunSetIfsJob(const spec::ConvertedJob&, JobContext&) {
  return absl::UnimplementedError("set_ifs jobs are not available in this build yet");
}

}  // namespace nimbus::server
