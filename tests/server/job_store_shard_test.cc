// Contract tests of the JobStore additions for sharded jobs and the result
// cache (docs/sharding.md, docs/result_cache.md), written against a plain
// JobStore&, run against every store kind (SQLite and PostgreSQL).
#include <gtest/gtest.h>

#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "server/job_store.h"
#include "tests/support/job_store_factory.h"
#include "tests/support/test_util.h"

namespace nimbus::server {
namespace {

constexpr TimeMs kT0 = 1'700'000'000'000;
constexpr TimeMs kLease = 10'000;

NewJob MakeJob(const std::string& id, uint32_t shards = 0, const std::string& sha = "") {
  NewJob job;
  job.id = id;
  job.name = "name-" + id;
  job.spec = "spec of " + id;
  job.progress_total = 1000;
  job.estimated_memory_bytes = 4096;
  job.owner = "alice";
  job.shard_count = shards;
  job.spec_sha256 = sha;
  return job;
}

std::vector<std::string> Ids(const std::vector<JobRecord>& jobs) {
  std::vector<std::string> ids;
  for (const JobRecord& j : jobs) ids.push_back(j.id);
  return ids;
}

// Run against every store kind, like the rest of the JobStore contract.
class JobStoreShardTest : public ::testing::TestWithParam<testing::StoreKind> {
 protected:
  void SetUp() override {
    auto where = testing::StoreLocation::Fresh(GetParam(), dir_.path());
    if (absl::IsUnavailable(where.status())) GTEST_SKIP() << where.status().message();
    ASSERT_TRUE(where.ok()) << where.status();
    auto store = where->Open();
    ASSERT_TRUE(store.ok()) << store.status();
    store_ = std::move(*store);
  }
  JobStore& store() { return *store_; }

  // Claims the next job as `worker`; its id, or "" when nothing is claimable.
  std::string Claim(const std::string& worker, TimeMs now = kT0, uint32_t max_attempts = 0) {
    auto c = store().ClaimNext(worker, now, kLease, max_attempts);
    EXPECT_TRUE(c.ok()) << c.status();
    return c.ok() && c->has_value() ? (*c)->id : "";
  }
  void Succeed(const std::string& id, const std::string& worker) {
    Completion done;
    done.result_key = id;
    done.result_size = 10;
    done.result_sha256 = "ab";
    ASSERT_TRUE(store().Complete(id, worker, done, kT0 + 5).ok());
  }
  JobState StateOf(const std::string& id) { return store().Get(id)->state; }

  testing::TempDir dir_;
  std::unique_ptr<JobStore> store_;
};

TEST_P(JobStoreShardTest, CreateInsertsTheParentAndItsShards) {
  auto parent = store().Create(MakeJob("p", 3, "hash"), kT0);
  ASSERT_TRUE(parent.ok()) << parent.status();
  EXPECT_EQ(parent->state, JobState::kQueued);
  EXPECT_EQ(parent->shard_count, 3u);
  EXPECT_EQ(parent->shards_pending, 3u);
  EXPECT_EQ(parent->parent_id, "");
  EXPECT_EQ(parent->spec_sha256, "hash");
  auto shards = store().ListShards("p");
  ASSERT_TRUE(shards.ok()) << shards.status();
  ASSERT_EQ(Ids(*shards), (std::vector<std::string>{"p.shard-0", "p.shard-1", "p.shard-2"}));
  for (uint32_t k = 0; k < 3; ++k) {
    const JobRecord& s = (*shards)[k];
    EXPECT_EQ(s.parent_id, "p");
    EXPECT_EQ(s.shard_index, k);
    EXPECT_EQ(s.shard_count, 3u);
    EXPECT_EQ(s.spec, parent->spec);
    EXPECT_EQ(s.name, parent->name);
    EXPECT_EQ(s.owner, "alice");
    EXPECT_EQ(s.progress_total, 1000u);
    EXPECT_EQ(s.estimated_memory_bytes, 4096u);
    EXPECT_EQ(s.request_id, "");
    EXPECT_EQ(s.create_time, kT0);
    EXPECT_EQ(s.state, JobState::kQueued);
  }
  EXPECT_EQ(store().ListShards("nope").status().code(), absl::StatusCode::kNotFound);
  // An ordinary job has no shards.
  ASSERT_TRUE(store().Create(MakeJob("plain"), kT0).ok());
  EXPECT_TRUE(store().ListShards("plain")->empty());
  EXPECT_EQ(store().Get("plain")->shard_count, 0u);
}

TEST_P(JobStoreShardTest, ShardIdsAreNotZeroPaddedAndClaimInShardOrder) {
  ASSERT_TRUE(store().Create(MakeJob("p", 12), kT0).ok());
  std::vector<std::string> claimed;
  for (int i = 0; i < 12; ++i) claimed.push_back(Claim("w"));
  for (uint32_t k = 0; k < 12; ++k) EXPECT_EQ(claimed[k], ShardJobId("p", k));
  EXPECT_EQ(claimed[10], "p.shard-10");
  // The parent waits for its shards.
  EXPECT_EQ(Claim("w"), "");
}

TEST_P(JobStoreShardTest, IdempotentSubmitReturnsTheParent) {
  NewJob job = MakeJob("p", 2);
  job.request_id = "req";
  ASSERT_TRUE(store().Create(job, kT0).ok());
  NewJob again = job;
  again.id = "p2";
  auto r = store().Create(again, kT0 + 1);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_EQ(r->id, "p");
  EXPECT_EQ(store().ListShards("p")->size(), 2u);
}

TEST_P(JobStoreShardTest, TheLastShardToSucceedMakesTheParentClaimable) {
  ASSERT_TRUE(store().Create(MakeJob("p", 2), kT0).ok());
  ASSERT_TRUE(store().Create(MakeJob("later"), kT0 + 1).ok());
  EXPECT_EQ(Claim("w0"), "p.shard-0");
  EXPECT_EQ(Claim("w1"), "p.shard-1");
  Succeed("p.shard-1", "w1");
  EXPECT_EQ(store().Get("p")->shards_pending, 1u);
  // Still not claimable: the next job is the later one.
  EXPECT_EQ(Claim("w1"), "later");
  Succeed("p.shard-0", "w0");
  EXPECT_EQ(store().Get("p")->shards_pending, 0u);
  EXPECT_EQ(Claim("w0"), "p");
  Succeed("p", "w0");
  EXPECT_EQ(StateOf("p"), JobState::kSucceeded);
}

TEST_P(JobStoreShardTest, AFailedShardFailsTheParentAndCancelsItsSiblings) {
  ASSERT_TRUE(store().Create(MakeJob("p", 3), kT0).ok());
  EXPECT_EQ(Claim("w0"), "p.shard-0");
  EXPECT_EQ(Claim("w1"), "p.shard-1");
  Completion failed;
  failed.state = JobState::kFailed;
  failed.error = "out of memory";
  failed.error_code = int(absl::StatusCode::kResourceExhausted);
  ASSERT_TRUE(store().Complete("p.shard-1", "w1", failed, kT0 + 3).ok());
  auto parent = store().Get("p");
  EXPECT_EQ(parent->state, JobState::kFailed);
  EXPECT_EQ(parent->error, "shard 1 of 3: out of memory");
  EXPECT_EQ(parent->error_code, int(absl::StatusCode::kResourceExhausted));
  EXPECT_EQ(StateOf("p.shard-2"), JobState::kCancelled);  // was queued
  EXPECT_EQ(StateOf("p.shard-0"), JobState::kRunning);
  EXPECT_TRUE(store().Get("p.shard-0")->cancel_requested);
  // The running sibling learns of it at its next heartbeat.
  EXPECT_TRUE(*store().Heartbeat("p.shard-0", "w0", kT0 + 4, kLease, 1, 2));
  EXPECT_EQ(Claim("w2"), "");
}

TEST_P(JobStoreShardTest, AShardGivenUpByClaimNextFailsTheParent) {
  ASSERT_TRUE(store().Create(MakeJob("p", 2), kT0).ok());
  EXPECT_EQ(Claim("w0", kT0, 1), "p.shard-0");
  ASSERT_TRUE(store().AbandonAttempt("p.shard-0", "w0", "crashed", 13).ok());
  std::vector<JobRecord> given_up;
  auto c = store().ClaimNext("w1", kT0 + 1, kLease, 1, &given_up);
  ASSERT_TRUE(c.ok());
  EXPECT_EQ(Ids(given_up), std::vector<std::string>{"p.shard-0"});
  // shard-1 was cancelled with the parent, so nothing is left to claim.
  EXPECT_FALSE(c->has_value());
  auto parent = store().Get("p");
  EXPECT_EQ(parent->state, JobState::kFailed);
  EXPECT_EQ(parent->error.rfind("shard 0 of 2: ", 0), 0u) << parent->error;
  EXPECT_EQ(StateOf("p.shard-1"), JobState::kCancelled);
}

TEST_P(JobStoreShardTest, ACancelledShardCancelsTheParent) {
  ASSERT_TRUE(store().Create(MakeJob("p", 2), kT0).ok());
  EXPECT_EQ(Claim("w0"), "p.shard-0");
  Completion cancelled;
  cancelled.state = JobState::kCancelled;
  cancelled.error = "cancelled by request";
  cancelled.error_code = int(absl::StatusCode::kCancelled);
  ASSERT_TRUE(store().Complete("p.shard-0", "w0", cancelled, kT0 + 1).ok());
  EXPECT_EQ(StateOf("p"), JobState::kCancelled);
  EXPECT_EQ(store().Get("p")->error_code, int(absl::StatusCode::kCancelled));
  EXPECT_EQ(StateOf("p.shard-1"), JobState::kCancelled);
}

TEST_P(JobStoreShardTest, CancellingTheParentCascades) {
  ASSERT_TRUE(store().Create(MakeJob("p", 3), kT0).ok());
  EXPECT_EQ(Claim("w0"), "p.shard-0");
  auto after = store().RequestCancel("p", kT0 + 1);
  ASSERT_TRUE(after.ok());
  EXPECT_EQ(after->state, JobState::kCancelled);
  EXPECT_TRUE(store().Get("p.shard-0")->cancel_requested);
  EXPECT_EQ(StateOf("p.shard-0"), JobState::kRunning);
  EXPECT_EQ(StateOf("p.shard-1"), JobState::kCancelled);
  EXPECT_EQ(StateOf("p.shard-2"), JobState::kCancelled);
  EXPECT_EQ(Claim("w1"), "");
  // Its worker finishes the transition; the parent stays cancelled.
  Completion cancelled;
  cancelled.state = JobState::kCancelled;
  cancelled.error_code = int(absl::StatusCode::kCancelled);
  ASSERT_TRUE(store().Complete("p.shard-0", "w0", cancelled, kT0 + 2).ok());
  EXPECT_EQ(StateOf("p"), JobState::kCancelled);
}

TEST_P(JobStoreShardTest, ListingsAndUsageHideShards) {
  ASSERT_TRUE(store().Create(MakeJob("p", 3), kT0).ok());
  ASSERT_TRUE(store().Create(MakeJob("q"), kT0 + 1).ok());
  ListOptions options;
  EXPECT_EQ(Ids(store().List(options)->jobs), (std::vector<std::string>{"q", "p"}));
  options.owner = "alice";
  EXPECT_EQ(store().List(options)->jobs.size(), 2u);
  options.state = JobState::kQueued;
  EXPECT_EQ(store().List(options)->jobs.size(), 2u);
  options.include_shards = true;
  EXPECT_EQ(store().List(options)->jobs.size(), 5u);
  EXPECT_EQ(store().Usage("alice")->active_jobs, 2u);
}

TEST_P(JobStoreShardTest, DeleteTakesTheShardsAndWaitsForThem) {
  ASSERT_TRUE(store().Create(MakeJob("p", 2), kT0).ok());
  EXPECT_EQ(Claim("w0"), "p.shard-0");
  ASSERT_TRUE(store().RequestCancel("p", kT0 + 1).ok());
  // shard-0 still runs.
  EXPECT_EQ(store().Delete("p").code(), absl::StatusCode::kFailedPrecondition);
  Completion cancelled;
  cancelled.state = JobState::kCancelled;
  ASSERT_TRUE(store().Complete("p.shard-0", "w0", cancelled, kT0 + 2).ok());
  ASSERT_TRUE(store().Delete("p").ok());
  EXPECT_EQ(store().Get("p.shard-0").status().code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(store().Get("p.shard-1").status().code(), absl::StatusCode::kNotFound);
}

TEST_P(JobStoreShardTest, ExpiringAndUsageCountTopLevelJobsOnly) {
  ASSERT_TRUE(store().Create(MakeJob("p", 2), kT0).ok());
  for (int i = 0; i < 2; ++i) {
    const std::string id = Claim("w");
    Succeed(id, "w");
  }
  EXPECT_EQ(Claim("w"), "p");
  Succeed("p", "w");
  auto expiring = store().ListExpiring(kT0 + 100, 10);
  ASSERT_TRUE(expiring.ok());
  EXPECT_EQ(Ids(*expiring), std::vector<std::string>{"p"});
  EXPECT_EQ(store().Usage("alice")->result_bytes, 10u);
}

TEST_P(JobStoreShardTest, FindCachedFindsTheNewestSucceededTopLevelJob) {
  EXPECT_FALSE(store().FindCached("h", "alice")->has_value());
  ASSERT_TRUE(store().Create(MakeJob("old", 0, "h"), kT0).ok());
  ASSERT_TRUE(store().Create(MakeJob("new", 0, "h"), kT0 + 1).ok());
  ASSERT_TRUE(store().Create(MakeJob("other", 0, "g"), kT0 + 2).ok());
  EXPECT_FALSE(store().FindCached("h", "alice")->has_value());  // none finished
  EXPECT_EQ(Claim("w"), "old");
  Succeed("old", "w");
  EXPECT_EQ(Claim("w"), "new");
  Completion done;
  done.result_key = "new";
  ASSERT_TRUE(store().Complete("new", "w", done, kT0 + 50).ok());
  EXPECT_EQ((*store().FindCached("h", "alice"))->id, "new");
  EXPECT_FALSE(store().FindCached("h", "bob")->has_value());
  EXPECT_FALSE(store().FindCached("", "alice")->has_value());
  // Pinned or not does not matter; expired results are skipped.
  ASSERT_TRUE(store().SetPinned("new", true).ok());
  EXPECT_EQ((*store().FindCached("h", "alice"))->id, "new");
  ASSERT_TRUE(store().MarkResultExpired("new", kT0 + 60).ok());
  EXPECT_EQ((*store().FindCached("h", "alice"))->id, "old");
}

TEST_P(JobStoreShardTest, FindCachedIgnoresShards) {
  ASSERT_TRUE(store().Create(MakeJob("p", 2, "h"), kT0).ok());
  const std::string first = Claim("w");
  Succeed(first, "w");
  EXPECT_FALSE(store().FindCached("h", "alice")->has_value());
}

TEST_P(JobStoreShardTest, ACacheHitIsCreatedSucceeded) {
  NewJob hit = MakeJob("copy", 0, "h");
  hit.cached_from = "orig";
  hit.cached_result.result_key = "copy";
  hit.cached_result.result_size = 77;
  hit.cached_result.result_sha256 = "cd";
  auto r = store().Create(hit, kT0);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_EQ(r->state, JobState::kSucceeded);
  EXPECT_EQ(r->cached_from, "orig");
  EXPECT_EQ(r->result_key, "copy");
  EXPECT_EQ(r->result_size, 77u);
  EXPECT_EQ(r->result_sha256, "cd");
  EXPECT_EQ(r->end_time, kT0);
  EXPECT_EQ(r->progress_done, r->progress_total);
  EXPECT_EQ(Claim("w"), "");
  // It is itself a cache entry.
  EXPECT_EQ((*store().FindCached("h", "alice"))->id, "copy");
}

INSTANTIATE_TEST_SUITE_P(Stores, JobStoreShardTest,
                         ::testing::Values(testing::StoreKind::kSqlite,
                                           testing::StoreKind::kPostgres),
                         [](const ::testing::TestParamInfo<testing::StoreKind>& info) {
                           return testing::StoreKindName(info.param);
                         });

}  // namespace
}  // namespace nimbus::server
