// Contract tests of the claim order (docs/operator_guide.md "Claim order"):
// priorities, fair share between owners, and the fields of retries; and of
// the worker registry and the job event log beside the queue,
// written against a plain JobStore&, run against every store kind (SQLite
// and PostgreSQL). Expected claim sequences are worked out by hand from
// the rule.
#include <gtest/gtest.h>

#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "server/job_store.h"
#include "tests/support/job_store_factory.h"
#include "tests/support/test_util.h"

namespace nimbus::server {
namespace {

constexpr TimeMs kT0 = 1'700'000'000'000;
constexpr TimeMs kLease = 10'000;

class JobStoreQueueTest : public ::testing::TestWithParam<testing::StoreKind> {
 protected:
  void SetUp() override {
    auto where = testing::StoreLocation::Fresh(GetParam(), dir_.path());
    if (absl::IsUnavailable(where.status())) GTEST_SKIP() << where.status().message();
    ASSERT_TRUE(where.ok()) << where.status();
    where_ = *where;
    auto store = where_.Open();
    ASSERT_TRUE(store.ok()) << store.status();
    store_ = std::move(*store);
  }
  JobStore& store() { return *store_; }

  // Queues job `id` of `owner` at `priority`, created at `now`.
  void Queue(const std::string& id, const std::string& owner, int priority, TimeMs now,
             uint32_t shards = 0) {
    NewJob job;
    job.id = id;
    job.name = id;
    job.spec = "spec of " + id;
    job.owner = owner;
    job.priority = priority;
    job.shard_count = shards;
    auto r = store().Create(job, now);
    ASSERT_TRUE(r.ok()) << r.status();
  }
  // Claims the next job as `worker`; its id, or "" when nothing is claimable.
  std::string Claim(const std::string& worker = "w", TimeMs now = kT0 + 1000) {
    auto c = store().ClaimNext(worker, now, kLease);
    EXPECT_TRUE(c.ok()) << c.status();
    return c.ok() && c->has_value() ? (*c)->id : "";
  }
  void Finish(const std::string& id, const std::string& worker = "w") {
    ASSERT_TRUE(store().Complete(id, worker, Completion{}, kT0 + 2000).ok()) << id;
  }
  // The kinds of `id`'s events, oldest first, with the named field's value.
  std::vector<std::string> Kinds(const std::string& id, const std::string& field) {
    auto page = store().ListEvents(id, 0, 500);
    EXPECT_TRUE(page.ok()) << page.status();
    std::vector<std::string> out;
    if (!page.ok()) return out;
    for (const JobEvent& e : page->events) {
      std::string value;
      for (const auto& [k, v] : e.fields)
        if (k == field) value = v;
      out.push_back(e.kind + ":" + value);
    }
    return out;
  }

  testing::TempDir dir_;
  testing::StoreLocation where_;
  std::unique_ptr<JobStore> store_;
};

INSTANTIATE_TEST_SUITE_P(Stores, JobStoreQueueTest,
                         ::testing::Values(testing::StoreKind::kSqlite,
                                           testing::StoreKind::kPostgres,
                                           testing::StoreKind::kTimedSqlite),
                         [](const ::testing::TestParamInfo<testing::StoreKind>& info) {
                           return testing::StoreKindName(info.param);
                         });

TEST_P(JobStoreQueueTest, HigherPriorityIsClaimedFirstThenOldest) {
  Queue("low", "ann", 10, kT0 + 1);
  Queue("mid", "ann", 50, kT0 + 2);
  Queue("high-late", "ann", 90, kT0 + 4);
  Queue("high-early", "ann", 90, kT0 + 3);
  EXPECT_EQ(store().Get("low")->priority, 10);
  std::vector<std::string> order;
  for (int i = 0; i < 5; ++i) order.push_back(Claim());
  EXPECT_EQ(order, (std::vector<std::string>{"high-early", "high-late", "mid", "low", ""}));
}

TEST_P(JobStoreQueueTest, DefaultPriorityIsFifty) {
  NewJob job;
  job.id = "j";
  job.spec = "s";
  auto r = store().Create(job, kT0);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_EQ(r->priority, 50);
}

// Owner A floods 100 jobs, then B queues one; one claim at a time, each
// finished before the next: B is served by the second claim.
TEST_P(JobStoreQueueTest, OneOwnersFloodDoesNotStarveAnother) {
  for (int i = 0; i < 100; ++i) Queue(absl::StrCat("a", 100 + i), "A", 50, kT0 + i);
  Queue("b", "B", 50, kT0 + 500);
  std::vector<std::string> first_two;
  for (int i = 0; i < 2; ++i) {
    first_two.push_back(Claim());
    Finish(first_two.back());
  }
  // Both never served: A's older job first; then B, never served.
  EXPECT_EQ(first_two, (std::vector<std::string>{"a100", "b"}));
  // The rest are A's, oldest first.
  EXPECT_EQ(Claim(), "a101");
}

// Fewest RUNNING jobs first; a tie goes to the owner served longest ago.
TEST_P(JobStoreQueueTest, FairShareCountsRunningJobsThenLastClaim) {
  for (int i = 0; i < 3; ++i) Queue(absl::StrCat("a", i), "A", 50, kT0 + i);
  for (int i = 0; i < 3; ++i) Queue(absl::StrCat("b", i), "B", 50, kT0 + 10 + i);
  std::vector<std::string> order;
  order.push_back(Claim());  // a0: both 0 running, never served; A's job older
  order.push_back(Claim());  // b0: A has 1 running, B 0
  Finish("b0");
  // A 1 running, B 0: B again, although A was served longer ago.
  order.push_back(Claim());  // b1
  order.push_back(Claim());  // a1: 1 running each; A served longer ago
  Finish("a0");
  Finish("a1");
  order.push_back(Claim());  // a2: A 0 running, B 1
  order.push_back(Claim());  // b2: the last one
  EXPECT_EQ(order, (std::vector<std::string>{"a0", "b0", "b1", "a1", "a2", "b2"}));
}

TEST_P(JobStoreQueueTest, PriorityComesBeforeFairShare) {
  Queue("a-high", "A", 70, kT0 + 1);
  Queue("a-high2", "A", 70, kT0 + 2);
  Queue("b-low", "B", 30, kT0);
  EXPECT_EQ(Claim(), "a-high");
  // A has one running and B none, but B's job has the lower priority.
  EXPECT_EQ(Claim(), "a-high2");
  EXPECT_EQ(Claim(), "b-low");
}

// A lapsed lease is claimed again before queued jobs of its priority or
// lower, after queued jobs of a higher one.
TEST_P(JobStoreQueueTest, LapsedJobGoesBeforeQueuedJobsOfItsPriority) {
  Queue("old", "A", 50, kT0);
  ASSERT_EQ(Claim("gone", kT0 + 1), "old");
  Queue("same", "B", 50, kT0 + 2);
  Queue("higher", "B", 60, kT0 + 3);
  const TimeMs lapsed = kT0 + 1 + kLease + 1;
  EXPECT_EQ(Claim("w", lapsed), "higher");
  EXPECT_EQ(Claim("w", lapsed), "old");
  EXPECT_EQ(Claim("w", lapsed), "same");
}

TEST_P(JobStoreQueueTest, ShardsInheritTheirParentsPriority) {
  Queue("plain", "A", 70, kT0);
  Queue("p", "A", 80, kT0 + 1, 2);
  auto shards = store().ListShards("p");
  ASSERT_TRUE(shards.ok()) << shards.status();
  ASSERT_EQ(shards->size(), 2u);
  for (const JobRecord& s : *shards) EXPECT_EQ(s.priority, 80) << s.id;
  EXPECT_EQ(Claim(), ShardJobId("p", 0));
  EXPECT_EQ(Claim(), ShardJobId("p", 1));
  EXPECT_EQ(Claim(), "plain");
}

TEST_P(JobStoreQueueTest, SetPriorityReordersQueuedJobsAndTheirShards) {
  Queue("first", "A", 50, kT0);
  Queue("second", "A", 50, kT0 + 1);
  Queue("p", "A", 50, kT0 + 2, 2);
  auto r = store().SetPriority("second", 99);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_EQ(r->priority, 99);
  ASSERT_TRUE(store().SetPriority("p", 98).ok());
  EXPECT_EQ(store().Get(ShardJobId("p", 1))->priority, 98);
  EXPECT_EQ(Claim(), "second");
  EXPECT_EQ(Claim(), ShardJobId("p", 0));
  // A running job keeps its priority.
  auto running = store().SetPriority("second", 1);
  EXPECT_EQ(running.status().code(), absl::StatusCode::kFailedPrecondition) << running.status();
  EXPECT_NE(running.status().message().find("RUNNING"), std::string::npos);
  EXPECT_EQ(store().Get("second")->priority, 99);
  EXPECT_EQ(store().SetPriority("nope", 5).status().code(), absl::StatusCode::kNotFound);
}

TEST_P(JobStoreQueueTest, PrioritiesOutsideTheRangeAreRefusedNamingTheField) {
  Queue("q", "A", 0, kT0);
  Queue("q100", "A", 100, kT0);
  for (int bad : {-1, 101}) {
    auto set = store().SetPriority("q", bad);
    EXPECT_EQ(set.status().code(), absl::StatusCode::kInvalidArgument) << bad;
    EXPECT_NE(set.status().message().find("priority"), std::string::npos) << set.status();
    NewJob job;
    job.id = absl::StrCat("bad", bad);
    job.spec = "s";
    job.priority = bad;
    auto created = store().Create(job, kT0);
    EXPECT_EQ(created.status().code(), absl::StatusCode::kInvalidArgument) << bad;
    EXPECT_NE(created.status().message().find("priority"), std::string::npos);
    EXPECT_EQ(store().Get(job.id).status().code(), absl::StatusCode::kNotFound);
  }
  EXPECT_EQ(store().Get("q")->priority, 0);
}

TEST_P(JobStoreQueueTest, RetryLinkAndPriorityPersistAcrossReopen) {
  NewJob job;
  job.id = "again";
  job.spec = "s";
  job.owner = "A";
  job.priority = 77;
  job.retried_from = "original";
  ASSERT_TRUE(store().Create(job, kT0).ok());
  store_.reset();
  auto reopened = where_.Open();
  ASSERT_TRUE(reopened.ok()) << reopened.status();
  auto r = (*reopened)->Get("again");
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_EQ(r->retried_from, "original");
  EXPECT_EQ(r->priority, 77);
  ListOptions options;
  auto page = (*reopened)->List(options);
  ASSERT_TRUE(page.ok() && page->jobs.size() == 1u);
  EXPECT_EQ(page->jobs[0].retried_from, "original");
}

// The worker registry and the job event log, beside the queue.

TEST_P(JobStoreQueueTest, ReplicasRegisterRenewAndAreDroppedAfterRetention) {
  ASSERT_TRUE(store().RegisterWorker({"r2", "host-b", "0.1.0", kT0, 4, 2, 0, kT0}).ok());
  ASSERT_TRUE(store().RegisterWorker({"r1", "host-a", "0.1.0", kT0 + 5, 1, 8, 0, kT0 + 5}).ok());
  ASSERT_TRUE(store().RenewWorker("r2", 3, kT0 + 100).ok());
  auto list = store().ListWorkers();
  ASSERT_TRUE(list.ok()) << list.status();
  ASSERT_EQ(list->size(), 2u);
  EXPECT_EQ((*list)[0].replica_id, "r1");
  EXPECT_EQ((*list)[0].host, "host-a");
  EXPECT_EQ((*list)[0].worker_slots, 1u);
  EXPECT_EQ((*list)[0].threads_per_job, 8u);
  EXPECT_EQ((*list)[0].start_time, kT0 + 5);
  EXPECT_EQ((*list)[1].replica_id, "r2");
  EXPECT_EQ((*list)[1].jobs_running, 3u);
  EXPECT_EQ((*list)[1].last_heartbeat, kT0 + 100);
  EXPECT_EQ((*list)[1].version, "0.1.0");
  // r1's last heartbeat (kT0 + 5) is before the cutoff, r2's is not.
  auto pruned = store().PruneWorkers(kT0 + 50);
  ASSERT_TRUE(pruned.ok()) << pruned.status();
  EXPECT_EQ(*pruned, 1);
  EXPECT_EQ(store().RenewWorker("r1", 0, kT0 + 200).code(), absl::StatusCode::kNotFound);
  // A restart replaces the row.
  ASSERT_TRUE(
      store().RegisterWorker({"r2", "host-c", "0.2.0", kT0 + 300, 2, 2, 0, kT0 + 300}).ok());
  list = store().ListWorkers();
  ASSERT_TRUE(list.ok() && list->size() == 1u);
  EXPECT_EQ((*list)[0].host, "host-c");
  EXPECT_EQ((*list)[0].jobs_running, 0u);
  ASSERT_TRUE(store().UnregisterWorker("r2").ok());
  EXPECT_TRUE(store().ListWorkers()->empty());
}

TEST_P(JobStoreQueueTest, ClaimsAndLapsedLeasesAreLogged) {
  Queue("j", "ann", 50, kT0);
  ASSERT_TRUE(store().ClaimNext("r1/w0", kT0 + 1, kLease).ok());
  // r1 stops heartbeating; after its lease another replica takes the job.
  auto again = store().ClaimNext("r2/w0", kT0 + 2 + kLease, kLease);
  ASSERT_TRUE(again.ok() && again->has_value()) << again.status();
  EXPECT_EQ(Kinds("j", "worker"),
            (std::vector<std::string>{"claimed:r1/w0", "lease_lost:r1/w0", "claimed:r2/w0"}));
  EXPECT_EQ(Kinds("j", "attempt"),
            (std::vector<std::string>{"claimed:1", "lease_lost:1", "claimed:2"}));
  // A restart of a single-node server requeues and logs it too.
  ASSERT_TRUE(store().RequeueRunning().ok());
  EXPECT_EQ(Kinds("j", "reason").back(), "lease_lost:restart");
}

// A job created with its submitter is logged `submitted` in Create's own
// transaction, so the event precedes its claim; an idempotent repeat adds
// none, and a job created without one (a store-level caller) has none.
TEST_P(JobStoreQueueTest, CreateLogsTheSubmissionBeforeAnyClaim) {
  NewJob job;
  job.id = "j";
  job.spec = "spec of j";
  job.owner = "ann";
  job.request_id = "req";
  job.priority = 70;
  job.submitted_by = "ann";
  ASSERT_TRUE(store().Create(job, kT0).ok());
  job.id = "j-again";
  auto repeat = store().Create(job, kT0 + 1);
  ASSERT_TRUE(repeat.ok()) << repeat.status();
  EXPECT_EQ(repeat->id, "j");
  Queue("plain", "bob", 10, kT0 + 2);
  ASSERT_EQ(Claim(), "j");
  EXPECT_EQ(Kinds("j", "by"), (std::vector<std::string>{"submitted:ann", "claimed:"}));
  EXPECT_EQ(Kinds("j", "priority"), (std::vector<std::string>{"submitted:70", "claimed:"}));
  EXPECT_TRUE(Kinds("j-again", "by").empty());
  EXPECT_TRUE(Kinds("plain", "by").empty());
}

// The end is logged in Complete's own transaction: whoever sees the job
// finished sees its end event too.
TEST_P(JobStoreQueueTest, CompleteLogsTheEndWithTheResult) {
  Queue("ok", "ann", 50, kT0);
  Queue("bad", "ann", 40, kT0);
  ASSERT_EQ(Claim(), "ok");
  Completion done;
  done.result_size = 1234;
  done.result_sha256 = "ab12";
  ASSERT_TRUE(store().Complete("ok", "w", done, kT0 + 5).ok());
  EXPECT_EQ(Kinds("ok", "sha256"), (std::vector<std::string>{"claimed:", "succeeded:ab12"}));
  EXPECT_EQ(Kinds("ok", "size").back(), "succeeded:1234");
  ASSERT_EQ(Claim(), "bad");
  Completion failed;
  failed.state = JobState::kFailed;
  failed.error = "diverged";
  failed.error_code = static_cast<int>(absl::StatusCode::kInvalidArgument);
  ASSERT_TRUE(store().Complete("bad", "w", failed, kT0 + 6).ok());
  EXPECT_EQ(Kinds("bad", "message").back(), "failed:diverged");
  EXPECT_EQ(Kinds("bad", "code").back(), "failed:INVALID_ARGUMENT");
}

// A queued job's end is logged by the RequestCancel that ends it, in its
// transaction: once however many cancels follow, and also for a job that
// ran and went back to the queue; a running job's end is its worker's.
TEST_P(JobStoreQueueTest, RequestCancelLogsTheEndOfAQueuedJobOnce) {
  Queue("q", "ann", 50, kT0);
  ASSERT_TRUE(store().RequestCancel("q", kT0 + 1, "ann").ok());
  auto again = store().RequestCancel("q", kT0 + 2, "bob");
  ASSERT_TRUE(again.ok()) << again.status();
  EXPECT_EQ(again->state, JobState::kCancelled);
  EXPECT_EQ(Kinds("q", "by"), (std::vector<std::string>{"cancelled:ann"}));

  Queue("r", "ann", 50, kT0);
  ASSERT_EQ(Claim(), "r");
  auto running = store().RequestCancel("r", kT0 + 3, "ann");
  ASSERT_TRUE(running.ok()) << running.status();
  EXPECT_EQ(running->state, JobState::kRunning);
  EXPECT_EQ(Kinds("r", "by"), (std::vector<std::string>{"claimed:"}));

  Queue("back", "ann", 50, kT0);
  ASSERT_EQ(Claim(), "back");
  ASSERT_TRUE(store().Release("back", "w").ok());
  ASSERT_TRUE(store().RequestCancel("back", kT0 + 4, "cy").ok());
  EXPECT_EQ(Kinds("back", "by"), (std::vector<std::string>{"claimed:", "cancelled:cy"}));
}

TEST_P(JobStoreQueueTest, EventLogKeepsTheNewestThousandAndPages) {
  Queue("j", "ann", 50, kT0);
  for (int i = 1; i <= 1003; ++i)
    ASSERT_TRUE(store().AppendEvent("j", {0, kT0 + i, "warning", {{"n", absl::StrCat(i)}}}).ok());
  auto page = store().ListEvents("j", 0, 600);
  ASSERT_TRUE(page.ok()) << page.status();
  EXPECT_EQ(page->dropped, 3);
  ASSERT_EQ(page->events.size(), 500u);  // pages hold at most 500
  EXPECT_EQ(page->events.front().seq, 4);
  EXPECT_EQ(page->events.front().time, kT0 + 4);
  EXPECT_EQ(page->events.front().fields,
            (std::vector<std::pair<std::string, std::string>>{{"n", "4"}}));
  EXPECT_EQ(page->next_after, 503);
  page = store().ListEvents("j", page->next_after, 600);
  ASSERT_TRUE(page.ok());
  ASSERT_EQ(page->events.size(), 500u);
  EXPECT_EQ(page->events.back().seq, 1003);
  EXPECT_EQ(page->next_after, 0);
}

TEST_P(JobStoreQueueTest, EventFieldsAreBoundedAndOneLineEach) {
  Queue("j", "ann", 50, kT0);
  const std::string huge(1 << 20, 'x');
  ASSERT_TRUE(store()
                  .AppendEvent("j", {0, kT0, "failed", {{"message", "two\nlines"}, {"big", huge}}})
                  .ok());
  auto page = store().ListEvents("j", 0, 10);
  ASSERT_TRUE(page.ok() && page->events.size() == 1u);
  const auto& fields = page->events[0].fields;
  ASSERT_EQ(fields.size(), 2u);
  EXPECT_EQ(fields[0], (std::pair<std::string, std::string>{"message", "two lines"}));
  EXPECT_LE(fields[1].second.size(), kMaxEventFieldBytes + 64);  // the cut marker
  EXPECT_GT(fields[1].second.size(), 512u);
}

TEST_P(JobStoreQueueTest, DeletingAJobDeletesItsLog) {
  Queue("j", "ann", 50, kT0);
  ASSERT_TRUE(store().AppendEvent("j", {0, kT0, "submitted", {}}).ok());
  ASSERT_TRUE(store().RequestCancel("j", kT0 + 1, "ann").ok());
  ASSERT_TRUE(store().Delete("j").ok());
  auto page = store().ListEvents("j", 0, 10);
  ASSERT_TRUE(page.ok());
  EXPECT_TRUE(page->events.empty());
  EXPECT_EQ(page->dropped, 0);
}

}  // namespace
}  // namespace nimbus::server
