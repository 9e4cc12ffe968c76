// @brief Sharded chaos-game jobs (docs/sharding.md): the runner of one
// shard (a fixed chunk range, saved as a partial), the merge that adds the
// partials in shard order and finishes exactly as an unsharded run, and the
// parent's view that sums its shards' progress.
#pragma once

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "core/plan/job_plan.h"
#include "nimbus/v1/nimbus_service.pb.h"
#include "server/job_runner.h"
#include "server/job_store.h"

namespace nimbus::server {

/// Runs shard `index` of `count` of `plan`'s chaos game and writes its
/// partial (core/chaos/chaos_partial.h) to ctx.ResultScratchPath().
absl::Status RunShard(const JobPlan& plan, uint32_t index, uint32_t count, JobContext& ctx);

/// Reads shard k's partial whole.
using PartialReader = std::function<absl::StatusOr<std::string>(uint32_t shard)>;

/// The merge of a sharded job: adds the `count` partials in shard order and
/// writes the result as RunJobPlan would for the unsharded job.
absl::Status RunMerge(const JobPlan& plan, uint32_t count, const PartialReader& read,
                      JobContext& ctx);

/// Shards the server gives a job that did not choose (JobSpec.shards 0)
/// when it plots more than `auto_shard_iterations` points (0: never): one
/// per started `auto_shard_iterations`, at most spec::kMaxShards and the
/// run's chunks. 0 for an unsharded job.
uint32_t AutoShards(const JobPlan& plan, uint64_t auto_shard_iterations);

/// @brief The parent's view while its shards run: progress is the sum of
/// the shards' (`live_shard`'s done taken as `live_done`, fresher than the
/// store's last heartbeat), and a QUEUED parent whose shards have started
/// shows RUNNING. Sets Job.shards and Job.shards_succeeded.
void AggregateShards(const std::vector<JobRecord>& shards, v1::Job& parent_view,
                     const std::string& live_shard = "", uint64_t live_done = 0);

}  // namespace nimbus::server
