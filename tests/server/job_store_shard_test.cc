// The shard store's contract (ShardStore in server/job_store.h) and what
// shards mean to the queue and the holdings (docs/sharding.md), run against
// every store kind (SQLite and PostgreSQL).
#include <gtest/gtest.h>

#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "server/job_store.h"
#include "tests/support/job_store_contract.h"
#include "tests/support/test_util.h"

namespace nimbus::server {
namespace {

using namespace contract;  // NOLINT: the contract's helpers

NIMBUS_STORE_CONTRACT_SUITE(ShardStoreTest);

TEST_P(ShardStoreTest, CreateInsertsTheParentAndItsShards) {
  auto parent = store().Create(OwnedJob("p", 3, "hash"), kT0);
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
  ASSERT_TRUE(store().Create(OwnedJob("plain"), kT0).ok());
  EXPECT_TRUE(store().ListShards("plain")->empty());
  EXPECT_EQ(store().Get("plain")->shard_count, 0u);
}

TEST_P(ShardStoreTest, ShardIdsAreNotZeroPaddedAndClaimInShardOrder) {
  ASSERT_TRUE(store().Create(OwnedJob("p", 12), kT0).ok());
  std::vector<std::string> claimed;
  for (int i = 0; i < 12; ++i) claimed.push_back(Claim("w"));
  for (uint32_t k = 0; k < 12; ++k) EXPECT_EQ(claimed[k], ShardJobId("p", k));
  EXPECT_EQ(claimed[10], "p.shard-10");
  // The parent waits for its shards.
  EXPECT_EQ(Claim("w"), "");
}

TEST_P(ShardStoreTest, IdempotentSubmitReturnsTheParent) {
  NewJob job = OwnedJob("p", 2);
  job.request_id = "req";
  ASSERT_TRUE(store().Create(job, kT0).ok());
  NewJob again = job;
  again.id = "p2";
  auto r = store().Create(again, kT0 + 1);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_EQ(r->id, "p");
  EXPECT_EQ(store().ListShards("p")->size(), 2u);
}

TEST_P(ShardStoreTest, TheLastShardToSucceedMakesTheParentClaimable) {
  ASSERT_TRUE(store().Create(OwnedJob("p", 2), kT0).ok());
  ASSERT_TRUE(store().Create(OwnedJob("later"), kT0 + 1).ok());
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

TEST_P(ShardStoreTest, AFailedShardFailsTheParentAndCancelsItsSiblings) {
  ASSERT_TRUE(store().Create(OwnedJob("p", 3), kT0).ok());
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

TEST_P(ShardStoreTest, AShardGivenUpByClaimNextFailsTheParent) {
  ASSERT_TRUE(store().Create(OwnedJob("p", 2), kT0).ok());
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

TEST_P(ShardStoreTest, ACancelledShardCancelsTheParent) {
  ASSERT_TRUE(store().Create(OwnedJob("p", 2), kT0).ok());
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

TEST_P(ShardStoreTest, CancellingTheParentCascades) {
  ASSERT_TRUE(store().Create(OwnedJob("p", 3), kT0).ok());
  EXPECT_EQ(Claim("w0"), "p.shard-0");
  auto after = store().RequestCancel("p", kT0 + 1, "ann");
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

TEST_P(ShardStoreTest, ListingsAndUsageHideShards) {
  ASSERT_TRUE(store().Create(OwnedJob("p", 3), kT0).ok());
  ASSERT_TRUE(store().Create(OwnedJob("q"), kT0 + 1).ok());
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

TEST_P(ShardStoreTest, DeleteTakesTheShardsAndWaitsForThem) {
  ASSERT_TRUE(store().Create(OwnedJob("p", 2), kT0).ok());
  EXPECT_EQ(Claim("w0"), "p.shard-0");
  ASSERT_TRUE(store().RequestCancel("p", kT0 + 1, "ann").ok());
  // shard-0 still runs.
  EXPECT_EQ(store().Delete("p").code(), absl::StatusCode::kFailedPrecondition);
  Completion cancelled;
  cancelled.state = JobState::kCancelled;
  ASSERT_TRUE(store().Complete("p.shard-0", "w0", cancelled, kT0 + 2).ok());
  ASSERT_TRUE(store().Delete("p").ok());
  EXPECT_EQ(store().Get("p.shard-0").status().code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(store().Get("p.shard-1").status().code(), absl::StatusCode::kNotFound);
}

TEST_P(ShardStoreTest, ExpiringAndUsageCountTopLevelJobsOnly) {
  ASSERT_TRUE(store().Create(OwnedJob("p", 2), kT0).ok());
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

}  // namespace
}  // namespace nimbus::server
