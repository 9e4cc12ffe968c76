// @brief Whether the shared job store answers: a background thread asks it
// every interval and reports each change, so the gRPC health status of the
// service can follow the store (NOT_SERVING while PostgreSQL is down,
// SERVING again once it answers), and never blocks a gRPC thread.
#pragma once

#include <condition_variable>
#include <cstdint>
#include <functional>
#include <mutex>
#include <thread>

#include "absl/status/status.h"

namespace nimbus::server {

/// True when `read` shows the store answered: a success, or an answer about
/// the data (NOT_FOUND and the like). UNAVAILABLE, DEADLINE_EXCEEDED,
/// INTERNAL and UNKNOWN mean it did not.
bool StoreAnswered(const absl::Status& read);

/// Calls `check` every `interval_ms` while started; calls `report(up)` after
/// the first check and after each change of StoreAnswered(check()).
class StoreProbe {
 public:
  StoreProbe(std::function<absl::Status()> check, std::function<void(bool up)> report,
             int64_t interval_ms)
      : check_(std::move(check)), report_(std::move(report)), interval_ms_(interval_ms) {}
  ~StoreProbe() { Stop(); }

  void Start();
  /// Returns once the thread has ended; no report follows.
  void Stop();

 private:
  std::function<absl::Status()> check_;
  std::function<void(bool)> report_;
  int64_t interval_ms_;
  std::mutex mu_;
  std::condition_variable cv_;
  bool stop_ = false;
  std::thread thread_;
};

}  // namespace nimbus::server
