// What only the PostgreSQL store does (the shared contract is in
// sqlite_job_store_test.cc, run against both stores): migrations under an
// advisory lock, the change feed, previews and preview wishes.
#include <gtest/gtest.h>

#include <pqxx/pqxx>

#include <chrono>
#include <condition_variable>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "absl/status/status.h"
#include "server/job_store.h"
#include "tests/support/postgres_server.h"

namespace nimbus::server {
namespace {

constexpr TimeMs kT0 = 1'700'000'000'000;

class PostgresJobStoreTest : public ::testing::Test {
 protected:
  void SetUp() override {
    std::string why;
    testing::PostgresServer* pg = testing::PostgresServer::Shared(&why);
    if (pg == nullptr) GTEST_SKIP() << why;
    auto url = pg->NewDatabase();
    ASSERT_TRUE(url.ok()) << url.status();
    url_ = *url;
  }
  std::unique_ptr<JobStore> Open() {
    auto store = OpenPostgresJobStore(url_);
    EXPECT_TRUE(store.ok()) << store.status();
    return store.ok() ? std::move(*store) : nullptr;
  }
  int64_t QueryInt(const std::string& sql) {
    pqxx::connection c(url_);
    pqxx::nontransaction n(c);
    return n.exec1(sql)[0].as<int64_t>();
  }

  std::string url_;
};

NewJob MakeJob(const std::string& id) {
  NewJob job;
  job.id = id;
  job.spec = "spec of " + id;
  return job;
}

TEST_F(PostgresJobStoreTest, ReplicasStartingTogetherMigrateOnce) {
  // Eight replicas open a fresh database at the same moment.
  std::vector<std::thread> threads;
  std::mutex mu;
  std::vector<std::string> errors;
  for (int i = 0; i < 8; ++i) {
    threads.emplace_back([&] {
      auto store = OpenPostgresJobStore(url_);
      std::lock_guard<std::mutex> lock(mu);
      if (!store.ok()) errors.push_back(store.status().ToString());
    });
  }
  for (auto& t : threads) t.join();
  ASSERT_TRUE(errors.empty()) << errors.front();
  EXPECT_EQ(QueryInt("SELECT count(*) FROM nimbus_schema"), 1);
  EXPECT_EQ(QueryInt("SELECT max(version) FROM nimbus_schema"), 3);
  EXPECT_EQ(QueryInt("SELECT count(*) FROM pg_indexes WHERE indexname = 'jobs_request_id' "
                     "AND indexdef LIKE '%UNIQUE%WHERE%'"),
            1);
}

TEST_F(PostgresJobStoreTest, RefusesANewerSchema) {
  ASSERT_NE(Open(), nullptr);
  {
    pqxx::connection c(url_);
    pqxx::nontransaction n(c);
    n.exec("UPDATE nimbus_schema SET version = 99");
  }
  auto store = OpenPostgresJobStore(url_);
  EXPECT_EQ(store.status().code(), absl::StatusCode::kFailedPrecondition) << store.status();
  EXPECT_NE(store.status().message().find("99"), std::string::npos);
}

TEST_F(PostgresJobStoreTest, UnreachableServerIsUnavailableWithoutThePassword) {
  auto store = OpenPostgresJobStore(
      "postgresql://nimbus:s3cret@127.0.0.1:1/nimbus?connect_timeout=2");
  ASSERT_FALSE(store.ok());
  EXPECT_EQ(store.status().code(), absl::StatusCode::kUnavailable) << store.status();
  EXPECT_EQ(store.status().message().find("s3cret"), std::string::npos) << store.status();
  EXPECT_EQ(OpenPostgresJobStore("mysql://x").status().code(),
            absl::StatusCode::kInvalidArgument);
}

// Collects the feed's changes.
struct Feed {
  std::mutex mu;
  std::condition_variable cv;
  std::vector<JobChange> changes;
  // Waits for a change matching `pred`; false after a few seconds.
  template <typename Pred>
  bool Await(Pred pred) {
    std::unique_lock<std::mutex> lock(mu);
    return cv.wait_for(lock, std::chrono::seconds(10), [&] {
      for (const JobChange& c : changes)
        if (pred(c)) return true;
      return false;
    });
  }
};

TEST_F(PostgresJobStoreTest, FeedCarriesEveryReplicasChanges) {
  std::unique_ptr<JobStore> a = Open(), b = Open();
  ASSERT_NE(a, nullptr);
  ASSERT_NE(b, nullptr);
  Feed feed;
  a->SetChangeListener([&](const JobChange& c) {
    std::lock_guard<std::mutex> lock(feed.mu);
    feed.changes.push_back(c);
    feed.cv.notify_all();
  });
  // The listener is connected once it reports the (re)connection.
  ASSERT_TRUE(feed.Await([](const JobChange& c) { return c.job_id.empty(); }));

  // A submit on the other replica: claimable.
  ASSERT_TRUE(b->Create(MakeJob("j"), kT0).ok());
  EXPECT_TRUE(feed.Await([](const JobChange& c) { return c.job_id == "j" && c.claimable; }));
  ASSERT_TRUE(b->ClaimNext("b/w0", kT0 + 1, 1000).ok());
  ASSERT_TRUE(b->Heartbeat("j", "b/w0", kT0 + 2, 1000, 5, 10).ok());
  ASSERT_TRUE(b->PutPreview("j", 16, 1, "preview one").ok());
  EXPECT_TRUE(feed.Await([](const JobChange& c) { return c.job_id == "j" && c.preview; }));
  size_t plain = 0;
  {
    std::lock_guard<std::mutex> lock(feed.mu);
    for (const JobChange& c : feed.changes) plain += c.job_id == "j" && !c.claimable && !c.preview;
  }
  EXPECT_GE(plain, 2u);  // the claim and the heartbeat
  a->SetChangeListener(nullptr);
}

TEST_F(PostgresJobStoreTest, NewestPreviewWinsAndEndsWithTheJob) {
  std::unique_ptr<JobStore> s = Open();
  ASSERT_NE(s, nullptr);
  ASSERT_TRUE(s->Create(MakeJob("j"), kT0).ok());
  ASSERT_TRUE(s->ClaimNext("w", kT0 + 1, 1000).ok());
  EXPECT_EQ(s->LatestPreview("j", 16).status().code(), absl::StatusCode::kNotFound);
  const std::string binary("\x00\x01\xff preview", 11);
  ASSERT_TRUE(s->PutPreview("j", 16, 2, binary).ok());
  ASSERT_TRUE(s->PutPreview("j", 16, 1, "older, arriving late").ok());
  ASSERT_TRUE(s->PutPreview("j", 32, 1, "another resolution").ok());
  EXPECT_EQ(*s->LatestPreview("j", 16), binary);
  EXPECT_EQ(*s->LatestPreview("j", 32), "another resolution");
  ASSERT_TRUE(s->Complete("j", "w", Completion{}, kT0 + 2).ok());
  EXPECT_EQ(s->LatestPreview("j", 16).status().code(), absl::StatusCode::kNotFound);
}

TEST_F(PostgresJobStoreTest, PreviewWishesExpireUnlessRenewed) {
  std::unique_ptr<JobStore> s = Open();
  ASSERT_NE(s, nullptr);
  ASSERT_TRUE(s->WishPreviews("j", {{16, 0.5}, {64, 2}}, kT0 + 100).ok());
  auto wishes = s->PreviewWishes("j", kT0);
  ASSERT_TRUE(wishes.ok()) << wishes.status();
  ASSERT_EQ(wishes->size(), 2u);
  EXPECT_EQ((*wishes)[0].resolution, 16u);
  EXPECT_DOUBLE_EQ((*wishes)[0].interval_seconds, 0.5);
  EXPECT_EQ((*wishes)[1].resolution, 64u);
  ASSERT_TRUE(s->WishPreviews("j", {{64, 1}}, kT0 + 500).ok());
  wishes = s->PreviewWishes("j", kT0 + 200);
  ASSERT_TRUE(wishes.ok());
  ASSERT_EQ(wishes->size(), 1u);
  EXPECT_EQ((*wishes)[0].resolution, 64u);
  EXPECT_DOUBLE_EQ((*wishes)[0].interval_seconds, 1.0);
  EXPECT_TRUE(s->PreviewWishes("j", kT0 + 501)->empty());
}

// ---- Sharded jobs and the result cache (semantics agreed with the SQLite
// store's; docs/sharding.md) ----

NewJob Sharded(const std::string& id, uint32_t shards, const std::string& request_id = "") {
  NewJob job = MakeJob(id);
  job.spec = "sharded spec";
  job.name = "big";
  job.owner = "alice";
  job.progress_total = 100;
  job.estimated_memory_bytes = 1 << 20;
  job.shard_count = shards;
  job.spec_sha256 = "abc";
  job.request_id = request_id;
  return job;
}

std::string ClaimId(JobStore& s, TimeMs now, uint32_t max_attempts = 0,
                    std::vector<JobRecord>* given_up = nullptr) {
  auto c = s.ClaimNext("w", now, 1000, max_attempts, given_up);
  EXPECT_TRUE(c.ok()) << c.status();
  return c.ok() && c->has_value() ? (*c)->id : "";
}

TEST_F(PostgresJobStoreTest, ShardedCreateInsertsParentAndShardsOnce) {
  std::unique_ptr<JobStore> s = Open();
  ASSERT_NE(s, nullptr);
  auto parent = s->Create(Sharded("p", 3, "req"), kT0);
  ASSERT_TRUE(parent.ok()) << parent.status();
  EXPECT_EQ(parent->shard_count, 3u);
  EXPECT_EQ(parent->shards_pending, 3u);
  EXPECT_EQ(parent->spec_sha256, "abc");
  EXPECT_EQ(parent->parent_id, "");
  auto again = s->Create(Sharded("p2", 3, "req"), kT0 + 1);
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(again->id, "p");
  auto shards = s->ListShards("p");
  ASSERT_TRUE(shards.ok()) << shards.status();
  ASSERT_EQ(shards->size(), 3u);
  for (uint32_t k = 0; k < 3; ++k) {
    const JobRecord& sh = (*shards)[k];
    EXPECT_EQ(sh.id, "p.shard-" + std::to_string(k));
    EXPECT_EQ(sh.parent_id, "p");
    EXPECT_EQ(sh.shard_index, k);
    EXPECT_EQ(sh.shard_count, 3u);
    EXPECT_EQ(sh.spec, parent->spec);
    EXPECT_EQ(sh.name, "big");
    EXPECT_EQ(sh.owner, "alice");
    EXPECT_EQ(sh.progress_total, 100u);
    EXPECT_EQ(sh.estimated_memory_bytes, 1u << 20);
    EXPECT_EQ(sh.request_id, "");
    EXPECT_EQ(sh.create_time, kT0);
  }
  EXPECT_EQ(s->ListShards("nope").status().code(), absl::StatusCode::kNotFound);
  EXPECT_TRUE(s->ListShards("p.shard-0")->empty());
  // Listings and quotas see the parent only, unless shards are asked for.
  EXPECT_EQ(s->List({})->jobs.size(), 1u);
  ListOptions all;
  all.include_shards = true;
  EXPECT_EQ(s->List(all)->jobs.size(), 4u);
  EXPECT_EQ(s->Usage("alice")->active_jobs, 1u);
}

TEST_F(PostgresJobStoreTest, ParentIsClaimedForItsMergeOnlyAfterEveryShardSucceeded) {
  std::unique_ptr<JobStore> s = Open();
  ASSERT_NE(s, nullptr);
  ASSERT_TRUE(s->Create(Sharded("p", 3), kT0).ok());
  ASSERT_TRUE(s->Create(MakeJob("later"), kT0 + 1).ok());
  EXPECT_EQ(ClaimId(*s, kT0 + 2), "p.shard-0");
  EXPECT_EQ(ClaimId(*s, kT0 + 2), "p.shard-1");
  EXPECT_EQ(ClaimId(*s, kT0 + 2), "p.shard-2");
  EXPECT_EQ(ClaimId(*s, kT0 + 2), "later");
  EXPECT_EQ(ClaimId(*s, kT0 + 2), "");
  for (int k : {2, 0}) {
    ASSERT_TRUE(s->Complete("p.shard-" + std::to_string(k), "w", Completion{}, kT0 + 3).ok());
    EXPECT_EQ(ClaimId(*s, kT0 + 4), "");
  }
  EXPECT_EQ(s->Get("p")->shards_pending, 1u);
  ASSERT_TRUE(s->Complete("p.shard-1", "w", Completion{}, kT0 + 5).ok());
  EXPECT_EQ(s->Get("p")->shards_pending, 0u);
  EXPECT_EQ(ClaimId(*s, kT0 + 6), "p");
}

TEST_F(PostgresJobStoreTest, FailedShardFailsTheParentAndStopsTheOthers) {
  std::unique_ptr<JobStore> s = Open();
  ASSERT_NE(s, nullptr);
  ASSERT_TRUE(s->Create(Sharded("p", 3), kT0).ok());
  EXPECT_EQ(ClaimId(*s, kT0 + 1), "p.shard-0");
  EXPECT_EQ(ClaimId(*s, kT0 + 1), "p.shard-1");
  Completion failed;
  failed.state = JobState::kFailed;
  failed.error = "out of memory";
  failed.error_code = static_cast<int>(absl::StatusCode::kResourceExhausted);
  ASSERT_TRUE(s->Complete("p.shard-1", "w", failed, kT0 + 2).ok());
  auto p = s->Get("p");
  EXPECT_EQ(p->state, JobState::kFailed);
  EXPECT_EQ(p->error, "shard 1 of 3: out of memory");
  EXPECT_EQ(p->error_code, failed.error_code);
  EXPECT_EQ(p->end_time, kT0 + 2);
  auto running = s->Get("p.shard-0");
  EXPECT_EQ(running->state, JobState::kRunning);
  EXPECT_TRUE(running->cancel_requested);
  EXPECT_EQ(s->Get("p.shard-2")->state, JobState::kCancelled);
  EXPECT_EQ(ClaimId(*s, kT0 + 3), "");
  // The running shard's end changes nothing more.
  Completion cancelled;
  cancelled.state = JobState::kCancelled;
  ASSERT_TRUE(s->Complete("p.shard-0", "w", cancelled, kT0 + 4).ok());
  EXPECT_EQ(s->Get("p")->error, "shard 1 of 3: out of memory");
  EXPECT_EQ(s->Usage("alice")->active_jobs, 0u);
}

TEST_F(PostgresJobStoreTest, ShardOutOfAttemptsFailsTheParent) {
  std::unique_ptr<JobStore> s = Open();
  ASSERT_NE(s, nullptr);
  ASSERT_TRUE(s->Create(Sharded("p", 3), kT0).ok());
  // Both running shards' workers die; their leases lapse; one attempt each.
  EXPECT_EQ(ClaimId(*s, kT0 + 1, 1), "p.shard-0");
  EXPECT_EQ(ClaimId(*s, kT0 + 1, 1), "p.shard-1");
  std::vector<JobRecord> given_up;
  EXPECT_EQ(ClaimId(*s, kT0 + 5000, 1, &given_up), "");
  ASSERT_EQ(given_up.size(), 1u);
  EXPECT_EQ(given_up[0].id, "p.shard-0");
  auto p = s->Get("p");
  EXPECT_EQ(p->state, JobState::kFailed);
  EXPECT_EQ(p->error.rfind("shard 0 of 3: gave up after 1 attempts", 0), 0u) << p->error;
  EXPECT_EQ(p->error_code, static_cast<int>(absl::StatusCode::kInternal));
  EXPECT_TRUE(s->Get("p.shard-1")->cancel_requested);
  EXPECT_EQ(s->Get("p.shard-2")->state, JobState::kCancelled);
}

TEST_F(PostgresJobStoreTest, CancellingTheParentCascadesAndCancelledShardCancelsParent) {
  std::unique_ptr<JobStore> s = Open();
  ASSERT_NE(s, nullptr);
  ASSERT_TRUE(s->Create(Sharded("p", 3), kT0).ok());
  EXPECT_EQ(ClaimId(*s, kT0 + 1), "p.shard-0");
  auto p = s->RequestCancel("p", kT0 + 2);
  ASSERT_TRUE(p.ok()) << p.status();
  EXPECT_EQ(p->state, JobState::kCancelled);
  EXPECT_TRUE(s->Get("p.shard-0")->cancel_requested);
  EXPECT_EQ(s->Get("p.shard-1")->state, JobState::kCancelled);
  EXPECT_EQ(s->Get("p.shard-2")->state, JobState::kCancelled);

  ASSERT_TRUE(s->Create(Sharded("q", 2), kT0 + 3).ok());
  EXPECT_EQ(ClaimId(*s, kT0 + 4), "q.shard-0");
  Completion cancelled;
  cancelled.state = JobState::kCancelled;
  cancelled.error = "cancelled by request";
  cancelled.error_code = static_cast<int>(absl::StatusCode::kCancelled);
  ASSERT_TRUE(s->Complete("q.shard-0", "w", cancelled, kT0 + 5).ok());
  auto q = s->Get("q");
  EXPECT_EQ(q->state, JobState::kCancelled);
  EXPECT_EQ(q->error_code, static_cast<int>(absl::StatusCode::kCancelled));
  EXPECT_EQ(s->Get("q.shard-1")->state, JobState::kCancelled);
}

TEST_F(PostgresJobStoreTest, DeletingAParentDeletesItsShards) {
  std::unique_ptr<JobStore> s = Open();
  ASSERT_NE(s, nullptr);
  ASSERT_TRUE(s->Create(Sharded("p", 2), kT0).ok());
  EXPECT_EQ(s->Delete("p").code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_EQ(ClaimId(*s, kT0 + 1), "p.shard-0");
  ASSERT_TRUE(s->RequestCancel("p", kT0 + 2).ok());
  // shard-0 still runs (cancel requested): not yet.
  EXPECT_EQ(s->Delete("p").code(), absl::StatusCode::kFailedPrecondition);
  Completion cancelled;
  cancelled.state = JobState::kCancelled;
  ASSERT_TRUE(s->Complete("p.shard-0", "w", cancelled, kT0 + 3).ok());
  ASSERT_TRUE(s->Delete("p").ok());
  EXPECT_EQ(s->Get("p.shard-0").status().code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(s->Get("p.shard-1").status().code(), absl::StatusCode::kNotFound);
}

TEST_F(PostgresJobStoreTest, ResultCacheFindsTheNewestUnexpiredTopLevelSuccess) {
  std::unique_ptr<JobStore> s = Open();
  ASSERT_NE(s, nullptr);
  auto job = [](const std::string& id, const std::string& owner) {
    NewJob j = MakeJob(id);
    j.owner = owner;
    j.spec_sha256 = "hash";
    return j;
  };
  EXPECT_FALSE(s->FindCached("hash", "alice")->has_value());
  for (const char* id : {"old", "new", "bobs"})
    ASSERT_TRUE(s->Create(job(id, std::string(id) == "bobs" ? "bob" : "alice"), kT0).ok());
  for (int i = 0; i < 3; ++i) {
    const std::string id = ClaimId(*s, kT0 + 1);
    ASSERT_TRUE(s->Complete(id, "w", Completion{}, kT0 + 10 + i).ok());
  }
  auto hit = s->FindCached("hash", "alice");
  ASSERT_TRUE(hit.ok() && hit->has_value());
  EXPECT_EQ((*hit)->id, "new");
  ASSERT_TRUE(s->SetPinned("new", true).ok());  // pinned or not: still a hit
  ASSERT_TRUE(s->MarkResultExpired("new", kT0 + 20).ok());
  EXPECT_EQ((*s->FindCached("hash", "alice"))->id, "old");
  EXPECT_EQ((*s->FindCached("hash", "bob"))->id, "bobs");
  EXPECT_FALSE(s->FindCached("other", "alice")->has_value());
  // Shards never count, even succeeded ones.
  ASSERT_TRUE(s->Create(Sharded("p", 2), kT0 + 30).ok());
  EXPECT_EQ(ClaimId(*s, kT0 + 31), "p.shard-0");
  ASSERT_TRUE(s->Complete("p.shard-0", "w", Completion{}, kT0 + 99).ok());
  EXPECT_FALSE(s->FindCached("abc", "alice")->has_value());
}

}  // namespace
}  // namespace nimbus::server
