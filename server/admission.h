// Where submitted specs are validated: off the gRPC threads, because
// validation may parse an uploaded mesh or run a pilot census of the
// attractor (tens of milliseconds), and a gRPC thread must only move data.
#pragma once

#include <condition_variable>
#include <cstddef>
#include <deque>
#include <functional>
#include <mutex>
#include <thread>

namespace nimbus::server {

/// @brief One thread running submitted tasks in order, with a bounded
/// queue so a flood of submissions is refused rather than buffered.
class Admission {
 public:
  explicit Admission(size_t max_pending = 256);
  /// Runs what is queued, then stops.
  ~Admission();
  Admission(const Admission&) = delete;
  Admission& operator=(const Admission&) = delete;

  /// Queues `task`; false when `max_pending` tasks are already waiting.
  bool Post(std::function<void()> task);
  size_t max_pending() const { return max_pending_; }

 private:
  void Loop();

  const size_t max_pending_;
  std::mutex mu_;
  std::condition_variable cv_;
  std::deque<std::function<void()>> queue_;
  bool stopping_ = false;
  std::thread thread_;
};

}  // namespace nimbus::server
