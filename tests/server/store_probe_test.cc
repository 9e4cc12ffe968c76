// The store probe reports the store's reachability once at start and then
// only on changes, and classifies answers: a not-found job is the store
// answering, a lost connection is not.
#include "server/store_probe.h"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <mutex>
#include <thread>
#include <vector>

namespace nimbus::server {
namespace {

TEST(StoreProbe, ClassifiesStoreAnswers) {
  EXPECT_TRUE(StoreAnswered(absl::OkStatus()));
  EXPECT_TRUE(StoreAnswered(absl::NotFoundError("no job ~store-probe")));
  EXPECT_TRUE(StoreAnswered(absl::PermissionDeniedError("role")));
  EXPECT_FALSE(StoreAnswered(absl::UnavailableError("connection refused")));
  EXPECT_FALSE(StoreAnswered(absl::DeadlineExceededError("slow")));
  EXPECT_FALSE(StoreAnswered(absl::InternalError("server closed the connection")));
}

// The store follows a script of answers, one per check; the probe's reports
// are recorded until the script has been played.
TEST(StoreProbe, ReportsTheFirstStateAndEachChangeOnly) {
  const std::vector<absl::Status> script = {
      absl::NotFoundError("up"),         absl::NotFoundError("up"),
      absl::UnavailableError("down"),    absl::UnavailableError("down"),
      absl::UnavailableError("down"),    absl::NotFoundError("up again"),
      absl::NotFoundError("up again")};
  std::mutex mu;
  std::condition_variable cv;
  size_t checks = 0;
  std::vector<bool> reports;
  StoreProbe probe(
      [&] {
        std::lock_guard<std::mutex> lock(mu);
        const absl::Status s = script[std::min(checks, script.size() - 1)];
        ++checks;
        cv.notify_all();
        return s;
      },
      [&](bool up) {
        std::lock_guard<std::mutex> lock(mu);
        reports.push_back(up);
      },
      1);
  probe.Start();
  {
    std::unique_lock<std::mutex> lock(mu);
    cv.wait(lock, [&] { return checks > script.size() + 2; });
  }
  probe.Stop();
  EXPECT_EQ(reports, (std::vector<bool>{true, false, true}));
}

TEST(StoreProbe, StopEndsTheThreadWithoutFurtherReports) {
  std::atomic<int> checks{0};
  std::atomic<int> reports{0};
  StoreProbe probe(
      [&] {
        ++checks;
        return absl::UnavailableError("down");
      },
      [&](bool) { ++reports; }, 3'600'000);
  probe.Start();
  while (checks.load() == 0) std::this_thread::yield();
  probe.Stop();  // Wakes the hour-long wait.
  const int after = reports.load();
  EXPECT_EQ(checks.load(), 1);
  EXPECT_LE(after, 1);
  probe.Stop();
  EXPECT_EQ(reports.load(), after);
}

}  // namespace
}  // namespace nimbus::server
