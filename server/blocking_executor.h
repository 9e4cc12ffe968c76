// Where the gRPC handlers do anything that may block: job store calls (a
// SQLite write may wait seconds for another process's lock) and result files
// on disk. gRPC's callback threads are few and shared by every call, so one
// slow disk or database must not stall unrelated calls or the event loop.
#pragma once

#include <condition_variable>
#include <cstddef>
#include <deque>
#include <functional>
#include <mutex>
#include <thread>
#include <vector>

namespace nimbus::server {

/// @brief A few threads running posted tasks, with a bounded queue so an
/// overload is refused ("server busy") rather than buffered without limit.
class BlockingExecutor {
 public:
  BlockingExecutor(int threads, size_t max_pending);
  /// Runs every task already queued, then joins.
  ~BlockingExecutor();
  BlockingExecutor(const BlockingExecutor&) = delete;
  BlockingExecutor& operator=(const BlockingExecutor&) = delete;

  /// Queues `task`; false (and `task` dropped) when `max_pending` tasks are
  /// already waiting or the executor is shutting down.
  bool Post(std::function<void()> task);
  int threads() const { return int(threads_.size()); }
  size_t max_pending() const { return max_pending_; }

 private:
  void Loop();

  const size_t max_pending_;
  std::mutex mu_;
  std::condition_variable cv_;
  std::deque<std::function<void()>> queue_;
  bool stopping_ = false;
  std::vector<std::thread> threads_;
};

}  // namespace nimbus::server
