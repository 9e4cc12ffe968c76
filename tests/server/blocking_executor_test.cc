// The bounded pool that keeps store and disk work off gRPC threads.
#include "server/blocking_executor.h"

#include <gtest/gtest.h>

#include <atomic>
#include <future>
#include <set>
#include <thread>
#include <vector>

namespace nimbus::server {
namespace {

TEST(BlockingExecutor, RunsTasksConcurrentlyOffTheCallingThread) {
  // Two tasks that each wait for the other can only finish if both run at
  // once: a blocked task must not hold up the next one.
  std::promise<void> a_started, b_started;
  std::shared_future<void> a_ready = a_started.get_future().share();
  std::shared_future<void> b_ready = b_started.get_future().share();
  std::promise<std::thread::id> a_thread, b_thread;
  {
    BlockingExecutor e(2, 8);
    ASSERT_TRUE(e.Post([&] {
      a_started.set_value();
      b_ready.wait();
      a_thread.set_value(std::this_thread::get_id());
    }));
    ASSERT_TRUE(e.Post([&] {
      b_started.set_value();
      a_ready.wait();
      b_thread.set_value(std::this_thread::get_id());
    }));
  }  // the destructor waits for both
  const std::thread::id a = a_thread.get_future().get(), b = b_thread.get_future().get();
  EXPECT_NE(a, b);
  EXPECT_NE(a, std::this_thread::get_id());
}

TEST(BlockingExecutor, RefusesBeyondItsBoundAndDrainsOnDestruction) {
  std::promise<void> started, release;
  std::shared_future<void> gate = release.get_future().share();
  std::atomic<int> done{0};
  {
    BlockingExecutor e(1, 2);
    ASSERT_TRUE(e.Post([&started, gate, &done] {
      started.set_value();
      gate.wait();
      ++done;
    }));
    started.get_future().wait();  // the only thread is busy, the queue empty
    EXPECT_TRUE(e.Post([&done] { ++done; }));
    EXPECT_TRUE(e.Post([&done] { ++done; }));
    EXPECT_FALSE(e.Post([&done] { ++done; }));  // the caller answers "server busy"
    release.set_value();
  }
  EXPECT_EQ(done, 3);
}

}  // namespace
}  // namespace nimbus::server
