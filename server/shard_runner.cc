#include "server/shard_runner.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>

#include "absl/strings/str_cat.h"
#include "core/base/status_macros.h"
#include "core/chaos/chaos_partial.h"
#include "proto/spec_convert.h"
#include "server/chaos_runs.h"
#include "server/job_driver.h"

namespace nimbus::server {

namespace {

absl::StatusOr<ChaosGameParams> ShardableRun(const JobPlan& plan) {
  const ChaosGameParams* run = plan.shardable_run();
  if (run == nullptr)
    return absl::FailedPreconditionError(
        absl::StrCat("a ", std::string(KindName(plan.kind)), " job cannot be sharded"));
  return *run;
}

}  // namespace

absl::Status RunShard(const JobPlan& plan, uint32_t index, uint32_t count, JobContext& ctx) {
  NIMBUS_ASSIGN_OR_RETURN(ChaosGameParams params, ShardableRun(plan));
  std::tie(params.chunk_begin, params.chunk_end) =
      ChaosGame::ShardChunks(params.iterations, count, index);
  params.memory_budget = ctx.memory_budget();
  JobDriver d(plan, ctx);
  NIMBUS_ASSIGN_OR_RETURN(auto game, ChaosGame::Create(std::move(params), ctx.threads()));
  NIMBUS_RETURN_IF_ERROR(
      d.BeginPhase(JobPhase::kIterating, game->range_iterations(), plan.work.unit));
  NIMBUS_RETURN_IF_ERROR(d.RunRounds(ChaosRounds(*game, d, 0, {}, nullptr)));
  const ChaosGameStats stats = game->stats();
  const CountGrid counts = game->TakeCounts();
  // The partial is this shard's result; the merge reads and deletes it.
  return SaveChaosPartial(ctx.ResultScratchPath(), counts, stats);
}

absl::Status RunMerge(const JobPlan& plan, uint32_t count, const PartialReader& read,
                      JobContext& ctx) {
  NIMBUS_ASSIGN_OR_RETURN(const ChaosGameParams params, ShardableRun(plan));
  JobDriver d(plan, ctx);
  NIMBUS_RETURN_IF_ERROR(d.BeginPhase(JobPhase::kIterating, count, "shards merged"));
  const auto start = std::chrono::steady_clock::now();
  CountGrid counts(plan.frame.resolution, params.color.mode != ColorMode::kNone);
  ChaosGameStats stats;
  // Integer sums: the order cannot change them, but shard order keeps the
  // merge itself reproducible step by step.
  for (uint32_t k = 0; k < count; ++k) {
    if (d.interrupter()->WasInterrupted(k, count))
      return d.Check(absl::CancelledError("interrupted"));
    NIMBUS_ASSIGN_OR_RETURN(const std::string bytes, read(k));
    if (absl::Status st = AddChaosPartial(bytes, counts, stats); !st.ok())
      return absl::Status(st.code(), absl::StrCat("shard ", k, " of ", count, ": ", st.message()));
    NIMBUS_RETURN_IF_ERROR(d.Progress(k + 1, k + 1 == count));
  }
  // The merge's own cost; the finishing after it is the unsharded job's.
  const double add_ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
  spdlog::info("job={} event=merged shards={} add_partials_ms={:.0f}", ctx.job_id(), count, add_ms);
  return FinishChaosGame(plan, d, params, counts, stats, {});
}

uint32_t AutoShards(const JobPlan& plan, uint64_t auto_shard_iterations) {
  const ChaosGameParams* run = plan.shardable_run();
  if (auto_shard_iterations == 0 || run == nullptr || run->convergence.tolerance > 0 ||
      run->iterations <= auto_shard_iterations)
    return 0;
  const uint64_t want = (run->iterations + auto_shard_iterations - 1) / auto_shard_iterations;
  const uint64_t most = std::min<uint64_t>(spec::kMaxShards, ChaosGame::NumChunks(run->iterations));
  const uint64_t s = std::min(want, most);
  return s > 1 ? uint32_t(s) : 0;
}

void AggregateShards(const std::vector<JobRecord>& shards, v1::Job& view,
                     const std::string& live_shard, uint64_t live_done) {
  view.set_shards(uint32_t(shards.size()));
  uint64_t done = 0;
  uint32_t succeeded = 0;
  bool started = false;
  for (const JobRecord& s : shards) {
    succeeded += s.state == JobState::kSucceeded;
    started = started || s.state != JobState::kQueued;
    // A finished shard counts whole: its last heartbeat holds its total.
    if (s.state == JobState::kSucceeded) done += s.progress_total;
    else if (s.id == live_shard) done += live_done;
    else done += s.progress_done;
  }
  view.set_shards_succeeded(succeeded);
  if (view.state() != v1::JOB_STATE_QUEUED) return;  // the merge reports its own
  if (started) view.set_state(v1::JOB_STATE_RUNNING);
  auto* p = view.mutable_progress();
  p->set_phase(started ? v1::PROGRESS_PHASE_ITERATING : v1::PROGRESS_PHASE_UNSPECIFIED);
  p->set_done(std::min<uint64_t>(done, p->total()));
}

}  // namespace nimbus::server
