// What only the PostgreSQL store does (the shared contract is in
// job_queue_test.cc and the extensions' tests, run against both stores):
// migrations under an advisory lock, the change feed, previews and preview
// wishes, and the claim order's query plans over a deep queue.
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
#include "absl/strings/str_cat.h"
#include "server/job_store.h"
#include "server/postgres_claim_sql.h"
#include "tests/support/job_store_factory.h"

namespace nimbus::server {
namespace {

constexpr TimeMs kT0 = 1'700'000'000'000;

class PostgresJobStoreTest : public ::testing::Test {
 protected:
  void SetUp() override {
    absl::StatusOr<std::string> url = testing::FreshPostgresUrl();
    if (absl::IsUnavailable(url.status())) GTEST_SKIP() << url.status().message();
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
  EXPECT_EQ(QueryInt("SELECT max(version) FROM nimbus_schema"), 6);
  EXPECT_EQ(QueryInt("SELECT count(*) FROM pg_indexes WHERE indexname = 'jobs_owner_request_id' "
                     "AND indexdef LIKE '%UNIQUE%(owner, request_id)%WHERE%'"),
            1);
  EXPECT_EQ(QueryInt("SELECT count(*) FROM pg_indexes WHERE indexname = 'jobs_request_id'"), 0);
}

// A schema-5 database (before priorities) with a queued job: version 6
// gives the job the default priority, and it is claimed as before.
TEST_F(PostgresJobStoreTest, UpgradesASchemaFiveDatabase) {
  {
    std::unique_ptr<JobStore> fresh = Open();
    ASSERT_NE(fresh, nullptr);
  }
  {
    pqxx::connection c(url_);
    pqxx::work w(c);
    w.exec(
        "DROP TABLE owner_claims; DROP SEQUENCE owner_claim_seq; DROP TABLE workers; "
        "DROP TABLE job_events; "
        "DROP INDEX jobs_claim_order; DROP INDEX jobs_state_owner; "
        "ALTER TABLE jobs DROP COLUMN priority; ALTER TABLE jobs DROP COLUMN retried_from; "
        "UPDATE nimbus_schema SET version = 5; "
        "INSERT INTO jobs (id, name, state, spec, create_time, owner) "
        "VALUES ('old', 'o', 1, '\\x00', 1, 'ann')");
    w.commit();
  }
  std::unique_ptr<JobStore> store = Open();
  ASSERT_NE(store, nullptr);
  EXPECT_EQ(QueryInt("SELECT max(version) FROM nimbus_schema"), 6);
  auto old = store->Get("old");
  ASSERT_TRUE(old.ok()) << old.status();
  EXPECT_EQ(old->priority, 50);
  EXPECT_EQ(old->retried_from, "");
  EXPECT_EQ(old->owner, "ann");
  auto claimed = store->ClaimNext("w", kT0, 1000);
  ASSERT_TRUE(claimed.ok() && claimed->has_value()) << claimed.status();
  EXPECT_EQ((*claimed)->id, "old");
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

// The claim order's queries as PostgresJobStore::PickClaimable and
// RankOwners send them (their own text, with the values a claim binds),
// explained.
struct ClaimPlans {
  std::string top, lapsed, first_owner, next_owner, owners, pick;
};

ClaimPlans ExplainClaimOrder(const std::string& url) {
  pqxx::connection c(url);
  pqxx::nontransaction n(c);
  const auto plan = [&](const std::string& sql) {
    std::string out;
    for (const pqxx::row& r : n.exec("EXPLAIN " + sql)) out += r[0].as<std::string>() + "\n";
    return out;
  };
  constexpr char kClaimable[] =
      "state = 1 AND NOT cancel_requested AND shards_pending = 0 AND priority = 50";
  ClaimPlans p;
  // Prepared, so each plan is a custom one, as exec_params gets.
  n.exec(absl::StrCat("PREPARE top_priority(integer) AS ", kTopPrioritySql));
  p.top = plan(absl::StrCat("EXECUTE top_priority(", kAnyPriority, ")"));
  n.exec(absl::StrCat("PREPARE lapsed_lease(bigint, integer) AS ", kLapsedLeaseSql));
  p.lapsed = plan("EXECUTE lapsed_lease(1700000200000, 50)");
  // The recursive walk's two seeks, and the whole of it.
  p.first_owner =
      plan(absl::StrCat("SELECT owner FROM jobs WHERE ", kClaimable, " ORDER BY owner LIMIT 1"));
  p.next_owner = plan(absl::StrCat("SELECT owner FROM jobs WHERE ", kClaimable,
                                   " AND owner > 'owner-3' ORDER BY owner LIMIT 1"));
  n.exec(absl::StrCat("PREPARE rank_owners(integer) AS ", kRankOwnersSql));
  p.owners = plan("EXECUTE rank_owners(50)");
  n.exec(absl::StrCat("PREPARE owners_oldest(integer, text) AS ", kOwnersOldestSql));
  p.pick = plan("EXECUTE owners_oldest(50, 'owner-3')");
  return p;
}

size_t Occurrences(const std::string& text, const std::string& needle) {
  size_t n = 0;
  for (size_t at = text.find(needle); at != std::string::npos; at = text.find(needle, at + 1)) ++n;
  return n;
}

// Each query of the queue is answered from jobs_claim_order in its order
// (no Sort), never by a scan of jobs; RUNNING jobs are counted from
// jobs_state_owner (the lapsed-lease probe sorts only the running ones).
void ExpectClaimOrderIndexed(const ClaimPlans& p) {
  for (const std::string* queue : {&p.top, &p.first_owner, &p.next_owner, &p.owners, &p.pick}) {
    EXPECT_NE(queue->find("using jobs_claim_order"), std::string::npos) << *queue;
    EXPECT_EQ(queue->find("Sort"), std::string::npos) << *queue;
  }
  for (const std::string* any : {&p.top, &p.lapsed, &p.first_owner, &p.next_owner, &p.owners,
                                 &p.pick})
    EXPECT_EQ(any->find("Seq Scan on jobs"), std::string::npos) << *any;
  EXPECT_EQ(Occurrences(p.owners, "using jobs_claim_order"), 2u) << p.owners;
  EXPECT_NE(p.owners.find("using jobs_state_owner"), std::string::npos) << p.owners;
  EXPECT_NE(p.lapsed.find("jobs_state_owner"), std::string::npos) << p.lapsed;
}

// A deep queue: 10,000 claimable jobs of 10 owners, 100 of a higher
// priority, 20 running and 10,000 ended; explained as a flood leaves it
// (before autovacuum analyses it) and once analysed.
TEST_F(PostgresJobStoreTest, ClaimOrderQueriesUseTheirIndexesOverADeepQueue) {
  ASSERT_NE(Open(), nullptr);  // the schema
  pqxx::connection c(url_);
  {
    pqxx::work w(c);
    w.exec(
        "INSERT INTO jobs (id, state, spec, create_time, owner, priority, lease_expiry) "
        "SELECT 'j' || i, CASE WHEN i < 10100 THEN 1 WHEN i < 10120 THEN 2 ELSE 3 END, "
        "'\\x00'::bytea, 1700000000000 + i, 'owner-' || (i % 10), "
        "CASE WHEN i < 10000 THEN 50 ELSE 70 END, 1700000100000 "
        "FROM generate_series(0, 20119) AS i");
    w.exec("INSERT INTO owner_claims (owner, last_claim) VALUES ('owner-1', 1), ('owner-2', 2)");
    w.commit();
  }
  ASSERT_EQ(QueryInt("SELECT count(*) FROM jobs WHERE state = 1"), 10100);
  {
    SCOPED_TRACE("not analysed");
    ExpectClaimOrderIndexed(ExplainClaimOrder(url_));
  }
  pqxx::nontransaction(c).exec("ANALYZE");
  {
    SCOPED_TRACE("analysed");
    ExpectClaimOrderIndexed(ExplainClaimOrder(url_));
  }
}

}  // namespace
}  // namespace nimbus::server
