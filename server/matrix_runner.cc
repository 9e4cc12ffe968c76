// Runs IFS-matrix jobs. Placeholder until IFS matrices land.
#include "server/job_runner.h"

namespace nimbus::server {

absl::Status RunIfsMatrixJob(const spec::ConvertedJob&, JobContext&) {
  return absl::UnimplementedError("IFS-matrix jobs are not available in this build yet");
}

}  // namespace nimbus::server
