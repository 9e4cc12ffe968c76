// @brief Memory admission: what a job will hold at its peak, checked against
// the server's memory limit before the job is queued. Runs once per job, on
// the admission thread (never a gRPC thread, never again at run time: the
// estimate is stored with the job). ConvertSpec stays pure; this is the
// server's step after it.
//
//   NIMBUS_ASSIGN_OR_RETURN(MemoryAdmission m, AdmitMemory(plan, limits, threads));
//   record.estimated_memory_bytes = m.estimated_bytes;
#pragma once

#include <cstdint>

#include "absl/status/statusor.h"
#include "core/base/interrupter.h"
#include "core/plan/job_plan.h"
#include "proto/spec_convert.h"

namespace nimbus::server {

struct MemoryAdmission {
  /// Peak bytes the job is expected to hold on `threads` threads.
  uint64_t estimated_bytes = 0;
  /// Size of the pilot run that measured a chaos game's tiles; 0 when the
  /// cheap geometric bound was enough.
  uint64_t pilot_samples = 0;
};

/// Prices `plan` for a run on `threads` threads. RESOURCE_EXHAUSTED, naming
/// grid.resolution, when it exceeds limits.max_memory_bytes.
absl::StatusOr<MemoryAdmission> AdmitMemory(const JobPlan& plan, const spec::Limits& limits,
                                            int threads, Interrupter* interrupter = nullptr);

}  // namespace nimbus::server
