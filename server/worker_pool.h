// Worker threads that claim jobs from the store and run them. All heavy
// work (iteration, previews, VDB writing) happens here, never on gRPC threads.
#pragma once

#include <atomic>
#include <condition_variable>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "core/grid/count_grid.h"
#include "proto/spec_convert.h"
#include "server/job_hub.h"
#include "server/job_runner.h"
#include "server/job_store.h"
#include "server/result_store.h"

namespace nimbus::server {

struct WorkerOptions {
  int workers = 1;
  /// Engine threads per job; 0 = hardware threads / workers.
  int threads_per_job = 0;
  spec::Limits limits;
  TimeMs lease_ms = 30'000;
  TimeMs heartbeat_ms = 2'000;
  /// Identifies this process in leases.
  std::string instance_id = "nimbusd";
  /// Attempts a job gets; a job that would need more (its worker died, or
  /// its end could not be recorded) FAILS with its last attempt's error.
  /// 0: no limit.
  uint32_t max_attempts = 3;
  /// How long a replica that stopped heartbeating stays in the worker
  /// registry (listed as lost) before it is dropped.
  TimeMs registry_retention_ms = 24 * 3600 * 1000;
};

/// @brief A fixed pool of job workers.
class WorkerPool {
 public:
  WorkerPool(JobStore* store, ResultStore* results, JobHub* hub, WorkerOptions options);
  ~WorkerPool();

  void Start();
  /// Interrupts running jobs, gives them back to the queue and joins.
  void Stop();
  /// A job was queued: wake an idle worker.
  void Wake();
  /// Whether `job_id` runs in this process.
  bool IsRunning(const std::string& job_id);
  /// Fast path for cancellation of a job running in this process.
  void Cancel(const std::string& job_id);
  int threads_per_job() const { return threads_per_job_; }

  /// Keeps `coarse` as shard `shard`'s newest counts at `resolution` and
  /// returns the sum over the parent's shards kept so far, with the next
  /// preview sequence for the parent's watchers (shards share it).
  std::pair<CountGrid, uint64_t> SumParentPreview(const std::string& parent_id, uint32_t shard,
                                                  uint32_t resolution, CountGrid coarse);

 private:
  class Context;
  void Loop(int index);
  void RunJob(const JobRecord& job, const std::string& worker_id);
  absl::Status ConvertAndRun(const v1::JobSpec& spec, const JobRecord& record, JobContext& ctx);
  // Sharded jobs (docs/sharding.md): the runner for a shard or a merge.
  absl::Status RunShardOrMerge(const JobPlan& plan, const JobRecord& record, JobContext& ctx);
  // Publishes a sharded job's parent view (its shards' progress summed)
  // to the parent's watchers; `live_done` is shard `shard_id`'s progress.
  void PublishParent(const std::string& parent_id, const std::string& shard_id,
                     uint64_t live_done);
  // Stores the end of an attempt; false when it could not (see
  // worker_pool.cc for what a failing store gets).
  bool RecordEnd(const std::string& id, const std::string& worker_id, const Completion& done);
  // Tells watchers of jobs the store failed for running out of attempts.
  void PublishGivenUp(const std::vector<JobRecord>& jobs);
  // The warning events of an end (the first kMaxWarningEvents).
  void LogWarnings(const std::string& id, const Completion& done);
  static constexpr int kMaxWarningEvents = 20;
  // The worker registry (server/worker_registry.h): this replica's row,
  // renewed every heartbeat_ms until Stop, and lost replicas dropped.
  void RegistryLoop();
  WorkerInfo RegistryRow();

  JobStore* store_;
  ResultStore* results_;
  JobHub* hub_;
  WorkerOptions options_;
  int threads_per_job_;

  std::mutex mu_;
  std::condition_variable wake_;
  std::condition_variable registry_wake_;
  bool stopping_ = false;
  uint64_t wake_generation_ = 0;
  std::map<std::string, std::shared_ptr<std::atomic<bool>>> running_;  // job id -> cancel flag
  // A sharded parent's preview state: the last sequence, and each shard's
  // newest coarse counts by (resolution, shard).
  struct ParentPreviews {
    uint64_t sequence = 0;
    std::map<std::pair<uint32_t, uint32_t>, CountGrid> latest;
  };
  std::map<std::string, ParentPreviews> parent_previews_;
  std::atomic<bool> shutdown_{false};
  std::vector<std::thread> threads_;
  std::thread registry_thread_;
  TimeMs start_time_ = 0;
};

}  // namespace nimbus::server
