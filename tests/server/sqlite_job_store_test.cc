// SQLite-only behaviour of its job store: schema, WAL, upgrades, readers
// beside a blocked writer. The contract every store keeps is in
// job_queue_test.cc and the extensions' tests.
#include <gtest/gtest.h>
#include <signal.h>
#include <sqlite3.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <future>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "absl/status/status.h"
#include "server/job_store.h"
#include "server/sqlite_claim_sql.h"
#include "tests/support/job_store_contract.h"
#include "tests/support/test_util.h"

namespace nimbus::server {
namespace {

using namespace contract;  // NOLINT: the contract's helpers
using ::nimbus::testing::TempDir;

std::unique_ptr<JobStore> OpenOrDie(const std::filesystem::path& path) {
  absl::StatusOr<std::unique_ptr<JobStore>> store = OpenSqliteJobStore(path.string());
  EXPECT_TRUE(store.ok()) << store.status();
  return store.ok() ? std::move(*store) : nullptr;
}

class SqliteJobStoreTest : public ::testing::Test {
 protected:
  void SetUp() override {
    store_ = OpenOrDie(db_path());
    ASSERT_NE(store_, nullptr);
  }
  std::filesystem::path db_path() const { return dir_ / "jobs.db"; }

  TempDir dir_;
  std::unique_ptr<JobStore> store_;
};

TEST(SqliteJobStoreOpenTest, FailureNamesThePath) {
  TempDir dir;
  const std::string path = (dir / "missing-dir" / "jobs.db").string();
  absl::StatusOr<std::unique_ptr<JobStore>> store = OpenSqliteJobStore(path);
  ASSERT_FALSE(store.ok());
  EXPECT_NE(store.status().message().find(path), std::string::npos) << store.status();
}

// Raw SQLite access to inspect what the store left on disk.
int64_t QueryInt(const std::string& path, const char* sql) {
  sqlite3* db = nullptr;
  int64_t value = -1;
  if (sqlite3_open(path.c_str(), &db) == SQLITE_OK) {
    sqlite3_stmt* stmt = nullptr;
    if (sqlite3_prepare_v2(db, sql, -1, &stmt, nullptr) == SQLITE_OK &&
        sqlite3_step(stmt) == SQLITE_ROW) {
      value = sqlite3_column_int64(stmt, 0);
    }
    sqlite3_finalize(stmt);
  }
  sqlite3_close(db);
  return value;
}

TEST_F(SqliteJobStoreTest, SchemaIsVersionedWalAndIndexed) {
  const std::string path = db_path().string();
  EXPECT_EQ(QueryInt(path, "PRAGMA user_version"), 7);
  // WAL is persistent in the file header, so a fresh connection reports it.
  EXPECT_EQ(QueryInt(path, "SELECT journal_mode = 'wal' FROM pragma_journal_mode"), 1);
  EXPECT_EQ(QueryInt(path,
                     "SELECT count(*) FROM sqlite_master WHERE type = 'index' AND "
                     "name = 'jobs_owner_request_id' AND sql LIKE '%UNIQUE%WHERE%'"),
            1);
  EXPECT_EQ(QueryInt(path,
                     "SELECT count(*) FROM pragma_index_info('jobs_owner_request_id') "
                     "WHERE name IN ('owner', 'request_id')"),
            2);
  EXPECT_EQ(QueryInt(path,
                     "SELECT count(*) FROM pragma_index_info('jobs_state_create') "
                     "WHERE name IN ('state', 'create_time')"),
            2);
}

// A clean close folds the WAL into the file and removes it: jobs.db alone
// holds every job, so a WAL damaged or lost after a clean stop loses none.
TEST_F(SqliteJobStoreTest, ClosingCheckpointsTheWalIntoTheFile) {
  ASSERT_TRUE(store_->Create(MakeJob("j-wal"), 1000).ok());
  store_.reset();
  const std::filesystem::path wal = db_path().string() + "-wal";
  EXPECT_FALSE(std::filesystem::exists(wal));
  // Garbage where the WAL was, as a damaged disk or a bad copy would leave.
  std::ofstream(wal, std::ios::binary) << std::string(4096, '\x5a');
  store_ = OpenOrDie(db_path());
  ASSERT_NE(store_, nullptr);
  EXPECT_TRUE(store_->Get("j-wal").ok());
}

TEST(SqliteJobStoreOpenTest, RefusesNewerSchema) {
  TempDir dir;
  const std::string path = (dir / "jobs.db").string();
  {
    absl::StatusOr<std::unique_ptr<JobStore>> store = OpenSqliteJobStore(path);
    ASSERT_TRUE(store.ok()) << store.status();
  }
  sqlite3* db = nullptr;
  ASSERT_EQ(sqlite3_open(path.c_str(), &db), SQLITE_OK);
  ASSERT_EQ(sqlite3_exec(db, "PRAGMA user_version = 99", nullptr, nullptr, nullptr), SQLITE_OK);
  sqlite3_close(db);
  absl::StatusOr<std::unique_ptr<JobStore>> store = OpenSqliteJobStore(path);
  EXPECT_EQ(store.status().code(), absl::StatusCode::kFailedPrecondition) << store.status();
  EXPECT_NE(store.status().message().find("99"), std::string::npos);
}

// The schema written by version 1 of this store, before error_code.
constexpr char kVersionOneSchema[] = R"sql(
CREATE TABLE jobs (
  id TEXT PRIMARY KEY NOT NULL,
  name TEXT NOT NULL DEFAULT '',
  state INTEGER NOT NULL,
  spec BLOB NOT NULL,
  request_id TEXT NOT NULL DEFAULT '',
  create_time INTEGER NOT NULL,
  start_time INTEGER NOT NULL DEFAULT 0,
  end_time INTEGER NOT NULL DEFAULT 0,
  attempts INTEGER NOT NULL DEFAULT 0,
  cancel_requested INTEGER NOT NULL DEFAULT 0,
  worker_id TEXT NOT NULL DEFAULT '',
  lease_expiry INTEGER NOT NULL DEFAULT 0,
  progress_done INTEGER NOT NULL DEFAULT 0,
  progress_total INTEGER NOT NULL DEFAULT 0,
  error TEXT NOT NULL DEFAULT '',
  result_key TEXT NOT NULL DEFAULT '',
  result_size INTEGER NOT NULL DEFAULT 0,
  result_sha256 TEXT NOT NULL DEFAULT '',
  warnings TEXT NOT NULL DEFAULT '',
  estimated_memory_bytes INTEGER NOT NULL DEFAULT 0
);
CREATE INDEX jobs_state_create ON jobs (state, create_time, id);
CREATE INDEX jobs_create ON jobs (create_time, id);
CREATE UNIQUE INDEX jobs_request_id ON jobs (request_id) WHERE request_id <> '';
INSERT INTO jobs (id, name, state, spec, create_time) VALUES ('queued', 'q', 1, x'00', 1);
INSERT INTO jobs (id, name, state, spec, create_time, error)
  VALUES ('failed', 'f', 4, x'00', 2, 'diverged');
INSERT INTO jobs (id, name, state, spec, create_time, error)
  VALUES ('cancelled', 'c', 5, x'00', 3, 'cancelled by request');
PRAGMA journal_mode=WAL;
PRAGMA user_version=1;
)sql";

// Runs `sql` on the database file at `path`, as an older binary would have.
void ExecOnFile(const std::string& path, const std::string& sql) {
  sqlite3* db = nullptr;
  ASSERT_EQ(sqlite3_open(path.c_str(), &db), SQLITE_OK);
  char* err = nullptr;
  EXPECT_EQ(sqlite3_exec(db, sql.c_str(), nullptr, nullptr, &err), SQLITE_OK) << err;
  sqlite3_free(err);
  sqlite3_close(db);
}

TEST(SqliteJobStoreOpenTest, UpgradesAVersionOneFile) {
  TempDir dir;
  const std::string path = (dir / "jobs.db").string();
  ExecOnFile(path, kVersionOneSchema);
  std::unique_ptr<JobStore> store = OpenOrDie(path);
  ASSERT_NE(store, nullptr);
  EXPECT_EQ(QueryInt(path, "PRAGMA user_version"), 7);
  // Old jobs keep everything and gain the code their end implies.
  const std::pair<const char*, int> expected[] = {{"queued", 0}, {"failed", 2}, {"cancelled", 1}};
  for (const auto& [id, code] : expected) {
    absl::StatusOr<JobRecord> r = store->Get(id);
    ASSERT_TRUE(r.ok()) << r.status();
    EXPECT_EQ(r->error_code, code) << id;
  }
  EXPECT_EQ(store->Get("failed")->error, "diverged");
  // The upgraded file takes new codes and opens again without a migration.
  ASSERT_TRUE(store->ClaimNext("w", kT0, 100).ok());
  Completion c;
  c.state = JobState::kFailed;
  c.error = "out of memory";
  c.error_code = static_cast<int>(absl::StatusCode::kResourceExhausted);
  ASSERT_TRUE(store->Complete("queued", "w", c, kT0 + 1).ok());
  store.reset();
  store = OpenOrDie(path);
  ASSERT_NE(store, nullptr);
  EXPECT_EQ(store->Get("queued")->error_code, 8);
  EXPECT_EQ(QueryInt(path, "PRAGMA user_version"), 7);
}

// A version-6 file (before priorities) with a queued job: version 7 gives
// it the default priority, and it is claimed as before.
TEST(SqliteJobStoreOpenTest, UpgradesAVersionSixFile) {
  TempDir dir;
  const std::string path = (dir / "jobs.db").string();
  OpenOrDie(path).reset();
  ExecOnFile(path,
             "DROP TABLE owner_claims; DROP TABLE workers; DROP TABLE job_events; "
             "DROP INDEX jobs_claim_order; DROP INDEX jobs_state_owner; "
             "ALTER TABLE jobs DROP COLUMN priority; ALTER TABLE jobs DROP COLUMN retried_from; "
             "INSERT INTO jobs (id, name, state, spec, create_time, owner) "
             "VALUES ('old', 'o', 1, x'00', 1, 'ann'); PRAGMA user_version=6;");
  std::unique_ptr<JobStore> store = OpenOrDie(path);
  ASSERT_NE(store, nullptr);
  EXPECT_EQ(QueryInt(path, "PRAGMA user_version"), 7);
  absl::StatusOr<JobRecord> old = store->Get("old");
  ASSERT_TRUE(old.ok()) << old.status();
  EXPECT_EQ(old->priority, 50);
  EXPECT_EQ(old->retried_from, "");
  EXPECT_EQ(old->owner, "ann");
  absl::StatusOr<std::optional<JobRecord>> claimed = store->ClaimNext("w", kT0, 100);
  ASSERT_TRUE(claimed.ok() && claimed->has_value()) << claimed.status();
  EXPECT_EQ((*claimed)->id, "old");
}

// The claim order's probes are satisfied by their indexes, ordering included:
// no scan or sort of the queue.
TEST_F(SqliteJobStoreTest, ClaimOrderQueriesUseTheirIndexes) {
  const std::string path = db_path().string();
  const auto plan = [&](const std::string& sql) {
    sqlite3* db = nullptr;
    EXPECT_EQ(sqlite3_open(path.c_str(), &db), SQLITE_OK);
    sqlite3_stmt* stmt = nullptr;
    EXPECT_EQ(sqlite3_prepare_v2(db, ("EXPLAIN QUERY PLAN " + sql).c_str(), -1, &stmt, nullptr),
              SQLITE_OK)
        << sqlite3_errmsg(db);
    std::string out;
    while (sqlite3_step(stmt) == SQLITE_ROW)
      out += std::string(reinterpret_cast<const char*>(sqlite3_column_text(stmt, 3))) + "\n";
    sqlite3_finalize(stmt);
    sqlite3_close(db);
    return out;
  };
  // The store's own text (its parameters left unbound: a plan does not
  // depend on them).
  const std::string top = plan(kSqliteTopPrioritySql);
  EXPECT_NE(top.find("jobs_claim_order"), std::string::npos) << top;
  EXPECT_EQ(top.find("TEMP B-TREE"), std::string::npos) << top;
  for (const char* sql : {kSqliteOwnerSeekFromSql, kSqliteOwnerSeekAfterSql}) {
    const std::string seek = plan(sql);
    EXPECT_NE(seek.find("jobs_claim_order"), std::string::npos) << seek;
    EXPECT_EQ(seek.find("TEMP B-TREE"), std::string::npos) << seek;
  }
  const std::string running = plan("SELECT count(*) FROM jobs WHERE state = 2 AND owner = 'a'");
  EXPECT_NE(running.find("jobs_state_owner"), std::string::npos) << running;
}

// Another connection holds the write lock, as a slow writer in another
// process would: writes wait for it, reads do not, and a read after the
// write went through sees it.
TEST_F(SqliteJobStoreTest, ReadsDoNotWaitForABlockedWrite) {
  CreateOrDie(*store_, "a", kT0);
  CreateOrDie(*store_, "b", kT0 + 1);
  sqlite3* db = nullptr;
  ASSERT_EQ(sqlite3_open(db_path().c_str(), &db), SQLITE_OK);
  ASSERT_EQ(sqlite3_exec(db, "BEGIN IMMEDIATE", nullptr, nullptr, nullptr), SQLITE_OK);
  std::future<absl::StatusOr<JobRecord>> cancel =
      std::async(std::launch::async, [&] { return store_->RequestCancel("a", kT0 + 2, "ann"); });
  // The write cannot finish while the lock is held; this also lets it reach
  // SQLite and wait there, holding the store's write mutex.
  EXPECT_EQ(cancel.wait_for(std::chrono::milliseconds(300)), std::future_status::timeout);
  // The lock is held until every read has answered: a read that queued
  // behind the blocked write could only answer once that write had failed
  // (its busy timeout), and the cancel checked below would have failed.
  for (int i = 0; i < 10; ++i) {
    absl::StatusOr<JobRecord> b = store_->Get("b");
    absl::StatusOr<ListPage> page = store_->List({});
    ASSERT_TRUE(b.ok()) << b.status();
    ASSERT_TRUE(page.ok()) << page.status();
    EXPECT_EQ(page->jobs.size(), 2u);
  }
  EXPECT_EQ(cancel.wait_for(std::chrono::seconds(0)), std::future_status::timeout)
      << "the cancel ended while the lock was held";
  ASSERT_EQ(sqlite3_exec(db, "ROLLBACK", nullptr, nullptr, nullptr), SQLITE_OK);
  sqlite3_close(db);
  absl::StatusOr<JobRecord> cancelled = cancel.get();
  ASSERT_TRUE(cancelled.ok()) << cancelled.status();
  EXPECT_EQ(cancelled->state, JobState::kCancelled);
  absl::StatusOr<JobRecord> a = store_->Get("a");
  ASSERT_TRUE(a.ok());
  EXPECT_EQ(a->state, JobState::kCancelled);
  EXPECT_EQ(a->error_code, 1);
}

TEST(SqliteJobStoreOpenTest, UpgradesAVersionTwoFileWithOwnersAndAPokesTable) {
  TempDir dir;
  const std::string path = (dir / "jobs.db").string();
  // Version 2 = version 1 plus error_code.
  ExecOnFile(path, std::string(kVersionOneSchema) +
                       "ALTER TABLE jobs ADD COLUMN error_code INTEGER NOT NULL DEFAULT 0;"
                       "PRAGMA user_version=2;");
  std::unique_ptr<JobStore> store = OpenOrDie(path);
  ASSERT_NE(store, nullptr);
  EXPECT_EQ(QueryInt(path, "PRAGMA user_version"), 7);
  EXPECT_EQ(QueryInt(path, "SELECT count(*) FROM pokes"), 0);
  // Version 5: old jobs are top-level, unsharded and not in the cache.
  EXPECT_EQ(QueryInt(path,
                     "SELECT count(*) FROM jobs WHERE parent_id <> '' OR shard_count <> 0 "
                     "OR spec_sha256 <> '' OR cached_from <> ''"),
            0);
  EXPECT_EQ(store->Get("failed")->error, "diverged");
  ASSERT_TRUE(store->ClaimNext("w", kT0, 100).ok());
  EXPECT_TRUE(store->AddPoke("queued", Push(0, 1)).ok());
}

}  // namespace
}  // namespace nimbus::server
