// The claim order (docs/operator_guide.md "Claim order") end to end: three
// nimbusd replicas of one worker slot each on one PostgreSQL queue, two
// principals flooding it with small jobs at a low priority (queued while a
// third principal's jobs hold the slots), then a few at a high one while
// the low ones still wait. The run is judged afterwards by
// the oracle in tests/support/claim_order_oracle.h, from the times the test
// saw each submission committed and the claim stamps of the job event logs.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/str_join.h"
#include "client/nimbus_client.h"
#include "google/protobuf/util/time_util.h"
#include "tests/support/claim_order_oracle.h"
#include "tests/support/e2e_clients.h"
#include "tests/support/job_store_factory.h"
#include "tests/support/nimbusd_process.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

using client::NimbusClient;
using google::protobuf::util::TimeUtil;
using testing::ClaimedJob;
using ::testing::IsEmpty;
using Clock = std::chrono::steady_clock;

constexpr int kReplicas = 3;
constexpr int kSlots = kReplicas;  // --workers 1 each
constexpr char kAlice[] = "alice-token-0123456789abcdef";
constexpr char kBob[] = "bob-token-0123456789abcdef00";
constexpr char kCarol[] = "carol-token-0123456789abcdef";
constexpr int kLow = 10, kHigh = 90;

int64_t SystemMs() {
  return std::chrono::duration_cast<std::chrono::milliseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}

class ClaimOrderE2E : public ::testing::Test {
 protected:
  void SetUp() override {
    absl::StatusOr<std::string> url = testing::FreshPostgresUrl();
    if (absl::IsUnavailable(url.status())) GTEST_SKIP() << url.status().message();
    ASSERT_TRUE(url.ok()) << url.status();
    const std::filesystem::path tokens = dir_ / "tokens";
    std::ofstream(tokens) << kAlice << " alice\n" << kBob << " bob\n" << kCarol << " carol\n";
    std::filesystem::permissions(tokens, std::filesystem::perms::owner_read);
    for (int i = 0; i < kReplicas; ++i) {
      replicas_.push_back(std::make_unique<testing::NimbusdProcess>(
          dir_ / ("data-" + std::to_string(i)),
          std::vector<std::string>{"--store", *url, "--results-dir", (dir_ / "results").string(),
                                   "--replica-id", "replica" + std::to_string(i), "--workers", "1",
                                   "--threads-per-job", "1", "--heartbeat-ms", "100",
                                   "--min-free-disk-mib", "0", "--auth-tokens", tokens.string(),
                                   "--log-level", "warn"}));
      replicas_.back()->set_log_file(dir_ / ("replica-" + std::to_string(i) + ".log"));
      ASSERT_TRUE(replicas_.back()->Start().ok());
      alice_.push_back(testing::ConnectAs(replicas_.back()->target(), kAlice));
      bob_.push_back(testing::ConnectAs(replicas_.back()->target(), kBob));
      carol_.push_back(testing::ConnectAs(replicas_.back()->target(), kCarol));
      ASSERT_TRUE(alice_.back() && bob_.back() && carol_.back());
    }
  }

  // Submits through replica `via` and notes when the job was surely queued.
  void Submit(std::vector<std::unique_ptr<NimbusClient>>& as, const char* owner, int via,
              int priority) {
    v1::JobSpec spec = testing::SmallTetrahedronJob();
    // Tens of ms each, so a queue forms; each must really run (no cache).
    spec.mutable_chaos_game()->set_iterations(20'000'000);
    spec.set_no_cache(true);
    auto job = as[via % kReplicas]->Submit(spec, "", priority);
    ASSERT_TRUE(job.ok()) << job.status();
    ClaimedJob j;
    j.id = job->id();
    j.owner = owner;
    j.priority = priority;
    j.visible_ms = SystemMs();
    jobs_.push_back(j);
  }

  // Carol's long jobs, one per slot, once all of them run: while they do,
  // what is submitted queues up however fast or slow submissions are.
  std::vector<std::string> HoldEverySlot() {
    v1::JobSpec spec = testing::SmallTetrahedronJob();
    spec.mutable_chaos_game()->set_iterations(4'000'000'000);  // cancelled long before
    spec.set_no_cache(true);
    std::vector<std::string> ids;
    for (int i = 0; i < kSlots; ++i) {
      auto job = carol_[i]->Submit(spec, "", 100);
      EXPECT_TRUE(job.ok()) << job.status();
      if (job.ok()) ids.push_back(job->id());
    }
    const auto deadline = Clock::now() + std::chrono::seconds(60);
    for (const std::string& id : ids)
      while (Clock::now() < deadline) {
        auto got = carol_[0]->Get(id);
        if (got.ok() && got->state() == v1::JOB_STATE_RUNNING) break;
        std::this_thread::sleep_for(std::chrono::milliseconds(10));
      }
    EXPECT_LT(Clock::now(), deadline) << "Carol's jobs did not all start";
    return ids;
  }
  // Cancels them all at once (each replica's own), so the slots free
  // together: a worker sees its cancel at its next heartbeat.
  void Release(const std::vector<std::string>& held) {
    std::vector<std::thread> cancels;
    for (size_t i = 0; i < held.size(); ++i)
      cancels.emplace_back([&, i] {
        auto cancelled = carol_[i]->Cancel(held[i]);
        EXPECT_TRUE(cancelled.ok()) << cancelled.status();
      });
    for (std::thread& t : cancels) t.join();
  }

  // Waits until `n` of the jobs so far have left the queue.
  void AwaitClaims(size_t n) {
    const auto deadline = Clock::now() + std::chrono::seconds(60);
    while (Clock::now() < deadline) {
      size_t claimed = 0;
      for (const ClaimedJob& j : jobs_) {
        auto got = alice_[0]->Get(j.id);
        claimed += got.ok() && got->state() != v1::JOB_STATE_QUEUED;
      }
      if (claimed >= n) return;
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    FAIL() << "fewer than " << n << " jobs were claimed";
  }

  // Waits for `j` to end, then reads its claim and end stamps.
  void ReadStamps(ClaimedJob& j) {
    NimbusClient& c = j.owner == "alice" ? *alice_[1] : *bob_[1];
    auto done = c.Watch(j.id, {}, [](const v1::WatchJobResponse&) {});
    ASSERT_TRUE(done.ok()) << done.status();
    ASSERT_EQ(done->state(), v1::JOB_STATE_SUCCEEDED) << j.id << ": " << done->error();
    ASSERT_EQ(done->attempts(), 1u) << j.id;
    j.end_ms = TimeUtil::TimestampToMilliseconds(done->end_time());
    auto events = c.GetJobEvents(j.id, 0, 500);
    ASSERT_TRUE(events.ok()) << events.status();
    for (const v1::JobEvent& e : events->events())
      if (e.kind() == "claimed") {
        j.claim_ms = TimeUtil::TimestampToMilliseconds(e.time());
        return;
      }
    FAIL() << j.id << " has no claimed event";
  }

  int CountClaimedAfter(int priority, const std::string& owner, int64_t t) const {
    int n = 0;
    for (const ClaimedJob& j : jobs_)
      n += j.priority == priority && (owner.empty() || j.owner == owner) && j.claim_ms > t;
    return n;
  }

  testing::TempDir dir_;
  std::vector<std::unique_ptr<testing::NimbusdProcess>> replicas_;
  std::vector<std::unique_ptr<NimbusClient>> alice_, bob_, carol_;
  std::vector<ClaimedJob> jobs_;
};

// While a third principal's jobs hold every slot, Alice queues a flood,
// then Bob one; the slots are freed, and once a few have started, both
// queue high-priority jobs, alternating (Carol's jobs are not judged). The
// oracle's bounds with three slots: while a high job surely waited (from
// its SubmitJob's return to its claim stamp) at most two low jobs were
// claimed, by claimers that found every high job locked by another; from
// the time an owner's job heads its queue at its priority to its claim, at
// most 2 + 2 jobs of the other owner at that priority were claimed that the
// rule's running counts do not excuse (the rule's two, and claims racing
// each other). Some 2 s idle, 4 s beside three busy loops: 38 jobs over
// three slots.
TEST_F(ClaimOrderE2E, InterleavedFloodsOfTwoOwnersAtTwoPriorities) {
  constexpr int kLowEach = 16, kHighEach = 3;
  const std::vector<std::string> held = HoldEverySlot();
  ASSERT_EQ(held.size(), size_t{kSlots});
  for (int i = 0; i < kLowEach; ++i) ASSERT_NO_FATAL_FAILURE(Submit(alice_, "alice", i, kLow));
  const int64_t bob_arrives = SystemMs();
  for (int i = 0; i < kLowEach; ++i) ASSERT_NO_FATAL_FAILURE(Submit(bob_, "bob", i, kLow));
  Release(held);
  ASSERT_NO_FATAL_FAILURE(AwaitClaims(kSlots + 2));
  for (int i = 0; i < kHighEach; ++i) {
    ASSERT_NO_FATAL_FAILURE(Submit(bob_, "bob", i + 1, kHigh));
    ASSERT_NO_FATAL_FAILURE(Submit(alice_, "alice", i + 2, kHigh));
  }
  const int64_t highs_queued = jobs_.back().visible_ms;
  for (ClaimedJob& j : jobs_) ASSERT_NO_FATAL_FAILURE(ReadStamps(j));

  // The run tested something: Alice's flood waited whole when Bob's came,
  // and low jobs still waited when the high ones came.
  EXPECT_EQ(CountClaimedAfter(kLow, "alice", bob_arrives), kLowEach);
  EXPECT_GE(CountClaimedAfter(kLow, "", highs_queued), 2 * kSlots);

  EXPECT_THAT(testing::PriorityViolations(jobs_, kSlots), IsEmpty());
  EXPECT_THAT(testing::FairShareViolations(jobs_, kSlots), IsEmpty());
}

}  // namespace
}  // namespace nimbus
