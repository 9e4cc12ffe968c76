// The worker registry: every nimbusd replica sharing a job store registers
// a row at start and renews it with its heartbeat, so an operator can ask
// which replicas exist, whether they are alive, and what each runs
// (docs/operator_guide.md "Worker registry"). Beside the queue: the store
// implements it on its own tables.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/str_cat.h"

namespace nimbus::server {

/// @brief One replica's row.
struct WorkerInfo {
  std::string replica_id;
  std::string host;
  /// nimbusd's version.
  std::string version;
  /// Milliseconds since the Unix epoch.
  int64_t start_time = 0;
  /// Jobs the replica runs at once, and engine threads per job.
  uint32_t worker_slots = 0;
  uint32_t threads_per_job = 0;
  /// Jobs running on it at its last heartbeat.
  uint32_t jobs_running = 0;
  int64_t last_heartbeat = 0;
};

/// @brief Replicas sharing a store. All methods are thread-safe. A store
/// without a registry keeps none (the defaults).
class WorkerRegistry {
 public:
  virtual ~WorkerRegistry() = default;

  /// Inserts the row of `info.replica_id`, or replaces it (a restart).
  virtual absl::Status RegisterWorker(const WorkerInfo& info) {
    (void)info;
    return absl::OkStatus();
  }
  /// Renews a row: its last heartbeat becomes `now`, with the jobs running.
  /// NOT_FOUND when the row is gone (dropped while the replica was
  /// stalled): register again.
  virtual absl::Status RenewWorker(const std::string& replica_id, uint32_t jobs_running,
                                   int64_t now) {
    (void)replica_id, (void)jobs_running, (void)now;
    return absl::OkStatus();
  }
  /// Removes the row (a clean stop).
  virtual absl::Status UnregisterWorker(const std::string& replica_id) {
    (void)replica_id;
    return absl::OkStatus();
  }
  /// Drops rows whose last heartbeat is before `cutoff`; returns how many.
  virtual absl::StatusOr<int> PruneWorkers(int64_t cutoff) {
    (void)cutoff;
    return 0;
  }
  /// Every row, by replica id.
  virtual absl::StatusOr<std::vector<WorkerInfo>> ListWorkers() {
    return std::vector<WorkerInfo>();
  }
};

}  // namespace nimbus::server
