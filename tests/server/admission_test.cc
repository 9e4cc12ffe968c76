// The admission queue that keeps spec validation off gRPC threads.
#include "server/admission.h"

#include <gtest/gtest.h>

#include <atomic>
#include <future>
#include <vector>

namespace nimbus::server {
namespace {

TEST(Admission, RunsTasksInOrderOffTheCallingThread) {
  std::vector<int> order;
  std::promise<std::thread::id> ran_on;
  {
    Admission a;
    ASSERT_TRUE(a.Post([&] { ran_on.set_value(std::this_thread::get_id()); }));
    for (int i = 0; i < 5; ++i) ASSERT_TRUE(a.Post([&order, i] { order.push_back(i); }));
  }  // the destructor drains the queue
  EXPECT_NE(ran_on.get_future().get(), std::this_thread::get_id());
  EXPECT_EQ(order, (std::vector<int>{0, 1, 2, 3, 4}));
}

TEST(Admission, RefusesBeyondItsBoundAndStillAnswersEveryQueuedTask) {
  std::promise<void> started, release;
  std::shared_future<void> gate = release.get_future().share();
  std::atomic<int> done{0};
  {
    Admission a(3);
    ASSERT_TRUE(a.Post([&started, gate, &done] {
      started.set_value();
      gate.wait();
      ++done;
    }));
    started.get_future().wait();  // the first task is running, the queue empty
    for (int i = 0; i < 3; ++i) EXPECT_TRUE(a.Post([&done] { ++done; }));
    EXPECT_FALSE(a.Post([&done] { ++done; }));
    release.set_value();
  }  // destruction waits for every accepted task
  EXPECT_EQ(done, 4);
}

}  // namespace
}  // namespace nimbus::server
