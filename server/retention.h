// @brief The retention policy: results of jobs that ended more than the
// retention age ago, and assets no queued, running or pinned job needs that
// were last uploaded before then, are deleted by a background thread, never
// on gRPC threads. Pinned jobs keep their results and assets.
#pragma once

#include <condition_variable>
#include <cstdint>
#include <mutex>
#include <thread>

#include "server/asset_store.h"
#include "server/job_store.h"
#include "server/result_store.h"

namespace nimbus::server {

struct SweepCounts {
  int results = 0;
  int assets = 0;
};

/// @brief Sweeps every `interval_ms` while started.
class RetentionSweeper {
 public:
  RetentionSweeper(JobHoldings* store, ResultStore* results, AssetStore* assets,
                   int64_t retention_ms, int64_t interval_ms)
      : store_(store),
        results_(results),
        assets_(assets),
        retention_ms_(retention_ms),
        interval_ms_(interval_ms) {}
  ~RetentionSweeper() { Stop(); }

  void Start();
  void Stop();
  /// One sweep as of `now` (ms since the epoch). Errors are logged; the
  /// next sweep tries again.
  SweepCounts SweepOnce(TimeMs now);

 private:
  JobHoldings* store_;
  ResultStore* results_;
  AssetStore* assets_;
  int64_t retention_ms_;
  int64_t interval_ms_;
  std::mutex mu_;
  std::condition_variable cv_;
  bool stop_ = false;
  std::thread thread_;
};

/// How often to sweep for a retention age: a tenth of it, between 100 ms
/// (tests use ages of a second) and one minute.
int64_t SweepIntervalMs(int64_t retention_ms);

}  // namespace nimbus::server
