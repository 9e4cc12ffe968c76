// The job store contract tests, run against every store kind: the queue
// (tests/server/job_queue_test.cc) and each extension beside it
// (poke_store_test.cc, job_store_shard_test.cc, result_cache_index_test.cc).
// Jobs to insert, records to compare, and the fixture that opens a store.
#pragma once

#include <gtest/gtest.h>

#include <memory>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "server/job_store.h"
#include "tests/support/job_store_factory.h"
#include "tests/support/test_util.h"

namespace nimbus::server::contract {

inline constexpr TimeMs kT0 = 1'700'000'000'000;

// A job whose spec bytes depend on `spec_key` (its id when empty).
inline NewJob MakeJob(const std::string& id, const std::string& request_id = "",
                      const std::string& spec_key = "") {
  NewJob job;
  job.id = id;
  job.name = "name-" + id;
  job.spec = std::string("spec\0of ", 8) + (spec_key.empty() ? id : spec_key);
  job.request_id = request_id;
  return job;
}

inline void CreateOrDie(JobStore& store, const std::string& id, TimeMs now) {
  absl::StatusOr<JobRecord> r = store.Create(MakeJob(id), now);
  ASSERT_TRUE(r.ok()) << r.status();
}

inline std::vector<std::string> Ids(const std::vector<JobRecord>& jobs) {
  std::vector<std::string> ids;
  for (const JobRecord& j : jobs) ids.push_back(j.id);
  return ids;
}

inline void ExpectSameRecord(const JobRecord& a, const JobRecord& b) {
  EXPECT_EQ(a.id, b.id);
  EXPECT_EQ(a.name, b.name);
  EXPECT_EQ(a.state, b.state);
  EXPECT_EQ(a.spec, b.spec);
  EXPECT_EQ(a.request_id, b.request_id);
  EXPECT_EQ(a.create_time, b.create_time);
  EXPECT_EQ(a.start_time, b.start_time);
  EXPECT_EQ(a.end_time, b.end_time);
  EXPECT_EQ(a.attempts, b.attempts);
  EXPECT_EQ(a.cancel_requested, b.cancel_requested);
  EXPECT_EQ(a.worker_id, b.worker_id);
  EXPECT_EQ(a.lease_expiry, b.lease_expiry);
  EXPECT_EQ(a.progress_done, b.progress_done);
  EXPECT_EQ(a.progress_total, b.progress_total);
  EXPECT_EQ(a.error, b.error);
  EXPECT_EQ(a.result_key, b.result_key);
  EXPECT_EQ(a.result_size, b.result_size);
  EXPECT_EQ(a.result_sha256, b.result_sha256);
  EXPECT_EQ(a.warnings, b.warnings);
  EXPECT_EQ(a.estimated_memory_bytes, b.estimated_memory_bytes);
  EXPECT_EQ(a.error_code, b.error_code);
}

/// A job of "alice" with `shards` shards and spec hash `sha`.
inline NewJob OwnedJob(const std::string& id, uint32_t shards = 0, const std::string& sha = "") {
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

inline PokeRecord Push(int32_t body, double x) {
  PokeRecord p;
  p.body = body;
  p.x = x;
  return p;
}

/// @brief A fresh, empty store of the kind given as the parameter: SQLite
/// or PostgreSQL (a private server; skipped only when it is not installed),
/// or SQLite behind a TimedJobStore.
class StoreContractTest : public ::testing::TestWithParam<::nimbus::testing::StoreKind> {
 protected:
  void SetUp() override {
    absl::StatusOr<::nimbus::testing::StoreLocation> where =
        ::nimbus::testing::StoreLocation::Fresh(GetParam(), dir_.path());
    if (absl::IsUnavailable(where.status())) GTEST_SKIP() << where.status().message();
    ASSERT_TRUE(where.ok()) << where.status();
    where_ = *where;
    store_ = Reopen();
    ASSERT_NE(store_, nullptr);
  }
  // Another handle on the same store: a second replica, or a restart.
  std::unique_ptr<JobStore> Reopen() const {
    absl::StatusOr<std::unique_ptr<JobStore>> store = where_.Open();
    EXPECT_TRUE(store.ok()) << store.status();
    return store.ok() ? std::move(*store) : nullptr;
  }
  JobStore& store() { return *store_; }

  static constexpr TimeMs kLease = 10'000;
  // Claims the next job as `worker`; its id, or "" when nothing is claimable.
  std::string Claim(const std::string& worker, TimeMs now = kT0, uint32_t max_attempts = 0) {
    auto c = store().ClaimNext(worker, now, kLease, max_attempts);
    EXPECT_TRUE(c.ok()) << c.status();
    return c.ok() && c->has_value() ? (*c)->id : "";
  }
  // Completes a claimed job SUCCEEDED with a 10-byte result.
  void Succeed(const std::string& id, const std::string& worker) {
    Completion done;
    done.result_key = id;
    done.result_size = 10;
    done.result_sha256 = "ab";
    ASSERT_TRUE(store().Complete(id, worker, done, kT0 + 5).ok());
  }
  JobState StateOf(const std::string& id) { return store().Get(id)->state; }

  ::nimbus::testing::TempDir dir_;
  ::nimbus::testing::StoreLocation where_;
  std::unique_ptr<JobStore> store_;
};

/// GoogleTest's name of a store kind parameter ("Sqlite", "Postgres").
inline std::string StoreName(const ::testing::TestParamInfo<::nimbus::testing::StoreKind>& info) {
  return ::nimbus::testing::StoreKindName(info.param);
}

/// Declares contract suite `Suite` (a StoreContractTest) and runs it
/// against every store kind.
#define NIMBUS_STORE_CONTRACT_SUITE(Suite)                                                \
  class Suite : public ::nimbus::server::contract::StoreContractTest {};                  \
  INSTANTIATE_TEST_SUITE_P(Stores, Suite,                                                 \
                           ::testing::Values(::nimbus::testing::StoreKind::kSqlite,       \
                                             ::nimbus::testing::StoreKind::kPostgres,     \
                                             ::nimbus::testing::StoreKind::kTimedSqlite), \
                           ::nimbus::server::contract::StoreName)

}  // namespace nimbus::server::contract
