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
#include "tests/support/job_store_factory.h"
#include "tests/support/test_util.h"

namespace nimbus::server {
namespace {

using ::nimbus::testing::StoreKind;
using ::nimbus::testing::StoreKindName;
using ::nimbus::testing::StoreLocation;
using ::nimbus::testing::TempDir;

constexpr TimeMs kT0 = 1'700'000'000'000;

std::unique_ptr<JobStore> OpenOrDie(const std::filesystem::path& path) {
  absl::StatusOr<std::unique_ptr<JobStore>> store = OpenSqliteJobStore(path.string());
  EXPECT_TRUE(store.ok()) << store.status();
  return store.ok() ? std::move(*store) : nullptr;
}

// A job whose spec bytes depend on `spec_key` (its id when empty).
NewJob MakeJob(const std::string& id, const std::string& request_id = "",
               const std::string& spec_key = "") {
  NewJob job;
  job.id = id;
  job.name = "name-" + id;
  job.spec = std::string("spec\0of ", 8) + (spec_key.empty() ? id : spec_key);
  job.request_id = request_id;
  return job;
}

void CreateOrDie(JobStore& store, const std::string& id, TimeMs now) {
  absl::StatusOr<JobRecord> r = store.Create(MakeJob(id), now);
  ASSERT_TRUE(r.ok()) << r.status();
}

std::vector<std::string> Ids(const std::vector<JobRecord>& jobs) {
  std::vector<std::string> ids;
  for (const JobRecord& j : jobs) ids.push_back(j.id);
  return ids;
}

void ExpectSameRecord(const JobRecord& a, const JobRecord& b) {
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

// The JobStore contract, run against every store kind: SQLite and
// PostgreSQL (a private server; skipped only when it is not installed).
class JobStoreTest : public ::testing::TestWithParam<StoreKind> {
 protected:
  void SetUp() override {
    absl::StatusOr<StoreLocation> where = StoreLocation::Fresh(GetParam(), dir_.path());
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

  TempDir dir_;
  StoreLocation where_;
  std::unique_ptr<JobStore> store_;
};

INSTANTIATE_TEST_SUITE_P(Stores, JobStoreTest,
                         ::testing::Values(StoreKind::kSqlite, StoreKind::kPostgres),
                         [](const ::testing::TestParamInfo<StoreKind>& info) {
                           return StoreKindName(info.param);
                         });

TEST_P(JobStoreTest, CreateAndGetRoundTripEveryField) {
  NewJob job;
  job.id = "job-1";
  job.name = "fern";
  job.spec = std::string("\x00\x01\xff binary\0spec", 15);
  job.request_id = "req-1";
  job.progress_total = 1000;
  job.warnings = "w1\nw2";
  job.estimated_memory_bytes = (uint64_t{1} << 63) + 5;  // Beyond int64 range.

  absl::StatusOr<JobRecord> created = store_->Create(job, kT0);
  ASSERT_TRUE(created.ok()) << created.status();
  JobRecord expected;
  expected.id = job.id;
  expected.name = job.name;
  expected.state = JobState::kQueued;
  expected.spec = job.spec;
  expected.request_id = job.request_id;
  expected.create_time = kT0;
  expected.progress_total = job.progress_total;
  expected.warnings = job.warnings;
  expected.estimated_memory_bytes = job.estimated_memory_bytes;
  ExpectSameRecord(*created, expected);
  absl::StatusOr<JobRecord> got = store_->Get("job-1");
  ASSERT_TRUE(got.ok()) << got.status();
  ExpectSameRecord(*got, expected);

  // Drive it through claim, heartbeat and completion so every column holds a
  // distinctive value, then check each one reads back.
  absl::StatusOr<std::optional<JobRecord>> claimed = store_->ClaimNext("w-a", kT0 + 10, 500);
  ASSERT_TRUE(claimed.ok() && claimed->has_value()) << claimed.status();
  ASSERT_TRUE(store_->RequestCancel("job-1", kT0 + 15).ok());
  absl::StatusOr<bool> hb = store_->Heartbeat("job-1", "w-a", kT0 + 20, 500, 700, ~uint64_t{0} - 1);
  ASSERT_TRUE(hb.ok()) << hb.status();
  expected.state = JobState::kRunning;
  expected.start_time = kT0 + 10;
  expected.attempts = 1;
  expected.cancel_requested = true;
  expected.worker_id = "w-a";
  expected.lease_expiry = kT0 + 520;
  expected.progress_done = 700;
  expected.progress_total = ~uint64_t{0} - 1;
  got = store_->Get("job-1");
  ASSERT_TRUE(got.ok()) << got.status();
  ExpectSameRecord(*got, expected);

  Completion done;
  done.state = JobState::kSucceeded;
  done.error = "none really";
  done.result_key = "results/job-1.vdb";
  done.result_size = uint64_t{1} << 40;
  done.result_sha256 = std::string(64, 'a');
  done.warnings = "w3";
  ASSERT_TRUE(store_->Complete("job-1", "w-a", done, kT0 + 30).ok());
  expected.state = JobState::kSucceeded;
  expected.end_time = kT0 + 30;
  expected.worker_id = "";
  expected.lease_expiry = 0;
  expected.error = done.error;
  expected.result_key = done.result_key;
  expected.result_size = done.result_size;
  expected.result_sha256 = done.result_sha256;
  expected.warnings = "w3";
  got = store_->Get("job-1");
  ASSERT_TRUE(got.ok()) << got.status();
  ExpectSameRecord(*got, expected);
}

TEST_P(JobStoreTest, EmptySpecAndStringsRoundTrip) {
  NewJob job;
  job.id = "bare";
  ASSERT_TRUE(store_->Create(job, kT0).ok());
  absl::StatusOr<JobRecord> got = store_->Get("bare");
  ASSERT_TRUE(got.ok()) << got.status();
  EXPECT_EQ(got->spec, "");
  EXPECT_EQ(got->name, "");
  EXPECT_EQ(got->request_id, "");
}

TEST_P(JobStoreTest, GetUnknownIsNotFoundNamingTheId) {
  absl::StatusOr<JobRecord> got = store_->Get("no-such-job");
  EXPECT_EQ(got.status().code(), absl::StatusCode::kNotFound);
  EXPECT_NE(got.status().message().find("no-such-job"), std::string::npos) << got.status();
}

TEST_P(JobStoreTest, CreateIsIdempotentByRequestId) {
  absl::StatusOr<JobRecord> first = store_->Create(MakeJob("a", "req", "s"), kT0);
  ASSERT_TRUE(first.ok()) << first.status();
  // A retry carries a fresh id (the server mints one per call) but the same
  // key and spec.
  absl::StatusOr<JobRecord> again = store_->Create(MakeJob("b", "req", "s"), kT0 + 5);
  ASSERT_TRUE(again.ok()) << again.status();
  EXPECT_EQ(again->id, "a");
  EXPECT_EQ(again->create_time, kT0);
  EXPECT_EQ(store_->Get("b").status().code(), absl::StatusCode::kNotFound);
  // The same key for another spec is refused, naming the first job.
  absl::StatusOr<JobRecord> other = store_->Create(MakeJob("e", "req", "t"), kT0 + 6);
  EXPECT_EQ(other.status().code(), absl::StatusCode::kAlreadyExists) << other.status();
  EXPECT_NE(other.status().message().find("job a"), std::string::npos) << other.status();
  EXPECT_EQ(store_->Get("e").status().code(), absl::StatusCode::kNotFound);

  // Jobs without a key never collide with each other.
  ASSERT_TRUE(store_->Create(MakeJob("c"), kT0 + 1).ok());
  ASSERT_TRUE(store_->Create(MakeJob("d"), kT0 + 2).ok());
  absl::StatusOr<ListPage> page = store_->List({});
  ASSERT_TRUE(page.ok()) << page.status();
  EXPECT_EQ(Ids(page->jobs), (std::vector<std::string>{"d", "c", "a"}));
}

// A key belongs to its principal: another's use of the same key, for any
// spec, is a first use and makes a job of its own.
TEST_P(JobStoreTest, RequestIdsArePerPrincipal) {
  auto job = [](const char* id, const char* spec, const char* owner) {
    NewJob j = MakeJob(id, "req", spec);
    j.owner = owner;
    return j;
  };
  ASSERT_TRUE(store_->Create(job("a", "s", "alice"), kT0).ok());
  // Bob's key for another spec than Alice's is not a conflict ...
  absl::StatusOr<JobRecord> bob = store_->Create(job("b", "t", "bob"), kT0 + 1);
  ASSERT_TRUE(bob.ok()) << bob.status();
  EXPECT_EQ(bob->id, "b");
  // ... his retry finds his own job ...
  absl::StatusOr<JobRecord> again = store_->Create(job("b2", "t", "bob"), kT0 + 2);
  ASSERT_TRUE(again.ok()) << again.status();
  EXPECT_EQ(again->id, "b");
  // ... and Carol's key for Alice's very spec is a new job, not Alice's.
  absl::StatusOr<JobRecord> carol = store_->Create(job("c", "s", "carol"), kT0 + 3);
  ASSERT_TRUE(carol.ok()) << carol.status();
  EXPECT_EQ(carol->id, "c");
  EXPECT_EQ(carol->owner, "carol");
  EXPECT_EQ(store_->Get("a")->owner, "alice");
}

TEST_P(JobStoreTest, DuplicateIdIsAlreadyExists) {
  ASSERT_TRUE(store_->Create(MakeJob("a"), kT0).ok());
  absl::StatusOr<JobRecord> dup = store_->Create(MakeJob("a"), kT0 + 1);
  EXPECT_EQ(dup.status().code(), absl::StatusCode::kAlreadyExists) << dup.status();
  // The failed insert rolled back; the store is still usable.
  EXPECT_TRUE(store_->Create(MakeJob("b"), kT0 + 2).ok());
}

TEST_P(JobStoreTest, ListIsNewestFirstWithIdTieBreak) {
  CreateOrDie(*store_, "x", kT0 + 1);
  CreateOrDie(*store_, "b", kT0 + 2);
  CreateOrDie(*store_, "c", kT0 + 2);
  CreateOrDie(*store_, "a", kT0 + 3);
  absl::StatusOr<ListPage> page = store_->List({});
  ASSERT_TRUE(page.ok()) << page.status();
  EXPECT_EQ(Ids(page->jobs), (std::vector<std::string>{"a", "c", "b", "x"}));
  EXPECT_EQ(page->next_page_token, "");
}

TEST_P(JobStoreTest, ListPagesThroughSevenJobs) {
  // Two share a create_time so the cursor's id tie-break is exercised.
  const std::vector<TimeMs> times = {1, 2, 3, 4, 4, 5, 6};
  for (size_t i = 0; i < times.size(); ++i) {
    CreateOrDie(*store_, "job-" + std::to_string(i), kT0 + times[i]);
  }
  std::vector<std::string> seen;
  std::vector<size_t> sizes;
  ListOptions options;
  options.page_size = 3;
  for (int guard = 0; guard < 10; ++guard) {
    absl::StatusOr<ListPage> page = store_->List(options);
    ASSERT_TRUE(page.ok()) << page.status();
    sizes.push_back(page->jobs.size());
    for (const JobRecord& j : page->jobs) seen.push_back(j.id);
    if (page->next_page_token.empty()) break;
    options.page_token = page->next_page_token;
  }
  EXPECT_EQ(sizes, (std::vector<size_t>{3, 3, 1}));
  EXPECT_EQ(seen, (std::vector<std::string>{"job-6", "job-5", "job-4", "job-3", "job-2", "job-1",
                                            "job-0"}));
}

TEST_P(JobStoreTest, PageTokenStaysValidWhileNewJobsArrive) {
  for (int i = 0; i < 4; ++i) CreateOrDie(*store_, "old-" + std::to_string(i), kT0 + i);
  ListOptions options;
  options.page_size = 2;
  absl::StatusOr<ListPage> first = store_->List(options);
  ASSERT_TRUE(first.ok()) << first.status();
  CreateOrDie(*store_, "new", kT0 + 100);
  options.page_token = first->next_page_token;
  absl::StatusOr<ListPage> second = store_->List(options);
  ASSERT_TRUE(second.ok()) << second.status();
  EXPECT_EQ(Ids(second->jobs), (std::vector<std::string>{"old-1", "old-0"}));
}

TEST_P(JobStoreTest, ListFiltersByState) {
  for (int i = 0; i < 5; ++i) CreateOrDie(*store_, "j" + std::to_string(i), kT0 + i);
  absl::StatusOr<std::optional<JobRecord>> claimed = store_->ClaimNext("w", kT0 + 10, 1000);
  ASSERT_TRUE(claimed.ok() && claimed->has_value());  // j0
  ASSERT_TRUE(store_->RequestCancel("j3", kT0 + 11).ok());

  ListOptions options;
  options.state = JobState::kQueued;
  absl::StatusOr<ListPage> queued = store_->List(options);
  ASSERT_TRUE(queued.ok()) << queued.status();
  EXPECT_EQ(Ids(queued->jobs), (std::vector<std::string>{"j4", "j2", "j1"}));

  // Paging works under a filter too.
  options.page_size = 2;
  queued = store_->List(options);
  ASSERT_TRUE(queued.ok()) << queued.status();
  EXPECT_EQ(Ids(queued->jobs), (std::vector<std::string>{"j4", "j2"}));
  options.page_token = queued->next_page_token;
  queued = store_->List(options);
  ASSERT_TRUE(queued.ok()) << queued.status();
  EXPECT_EQ(Ids(queued->jobs), (std::vector<std::string>{"j1"}));
  EXPECT_EQ(queued->next_page_token, "");

  options = {};
  options.state = JobState::kRunning;
  absl::StatusOr<ListPage> running = store_->List(options);
  ASSERT_TRUE(running.ok());
  EXPECT_EQ(Ids(running->jobs), (std::vector<std::string>{"j0"}));
  options.state = JobState::kCancelled;
  absl::StatusOr<ListPage> cancelled = store_->List(options);
  ASSERT_TRUE(cancelled.ok());
  EXPECT_EQ(Ids(cancelled->jobs), (std::vector<std::string>{"j3"}));
  options.state = JobState::kFailed;
  absl::StatusOr<ListPage> failed = store_->List(options);
  ASSERT_TRUE(failed.ok());
  EXPECT_TRUE(failed->jobs.empty());
}

TEST_P(JobStoreTest, ListClampsPageSize) {
  for (int i = 0; i < 501; ++i) CreateOrDie(*store_, "j" + std::to_string(i), kT0 + i);
  auto count = [&](int page_size) -> size_t {
    ListOptions options;
    options.page_size = page_size;
    absl::StatusOr<ListPage> page = store_->List(options);
    EXPECT_TRUE(page.ok()) << page.status();
    EXPECT_FALSE(page->next_page_token.empty());
    return page.ok() ? page->jobs.size() : 0;
  };
  EXPECT_EQ(count(0), 50u);
  EXPECT_EQ(count(-7), 1u);
  EXPECT_EQ(count(1), 1u);
  EXPECT_EQ(count(10000), 500u);
}

TEST_P(JobStoreTest, ListRejectsGarbageToken) {
  ListOptions options;
  options.page_token = "not a token!";
  EXPECT_EQ(store_->List(options).status().code(), absl::StatusCode::kInvalidArgument);
  options.page_token = "bm9jb2xvbg";  // base64 of "nocolon"
  EXPECT_EQ(store_->List(options).status().code(), absl::StatusCode::kInvalidArgument);
}

TEST_P(JobStoreTest, ClaimTakesOldestFirst) {
  CreateOrDie(*store_, "second", kT0 + 2);
  CreateOrDie(*store_, "first", kT0 + 1);
  CreateOrDie(*store_, "third", kT0 + 3);

  absl::StatusOr<std::optional<JobRecord>> c = store_->ClaimNext("w1", kT0 + 100, 5000);
  ASSERT_TRUE(c.ok()) << c.status();
  ASSERT_TRUE(c->has_value());
  EXPECT_EQ((*c)->id, "first");
  EXPECT_EQ((*c)->state, JobState::kRunning);
  EXPECT_EQ((*c)->worker_id, "w1");
  EXPECT_EQ((*c)->start_time, kT0 + 100);
  EXPECT_EQ((*c)->lease_expiry, kT0 + 5100);
  EXPECT_EQ((*c)->attempts, 1u);

  c = store_->ClaimNext("w1", kT0 + 101, 5000);
  ASSERT_TRUE(c.ok() && c->has_value());
  EXPECT_EQ((*c)->id, "second");
  c = store_->ClaimNext("w2", kT0 + 102, 5000);
  ASSERT_TRUE(c.ok() && c->has_value());
  EXPECT_EQ((*c)->id, "third");
  c = store_->ClaimNext("w2", kT0 + 103, 5000);
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_FALSE(c->has_value());
}

TEST_P(JobStoreTest, TwoStoresOnOneFileNeverDoubleClaim) {
  std::unique_ptr<JobStore> other = Reopen();
  ASSERT_NE(other, nullptr);
  CreateOrDie(*store_, "j1", kT0 + 1);
  CreateOrDie(*other, "j2", kT0 + 2);

  absl::StatusOr<std::optional<JobRecord>> a = store_->ClaimNext("replica-a", kT0 + 10, 1000);
  absl::StatusOr<std::optional<JobRecord>> b = other->ClaimNext("replica-b", kT0 + 10, 1000);
  ASSERT_TRUE(a.ok() && a->has_value()) << a.status();
  ASSERT_TRUE(b.ok() && b->has_value()) << b.status();
  EXPECT_EQ((*a)->id, "j1");
  EXPECT_EQ((*b)->id, "j2");
  for (JobStore* s : {store_.get(), other.get()}) {
    absl::StatusOr<std::optional<JobRecord>> none = s->ClaimNext("late", kT0 + 20, 1000);
    ASSERT_TRUE(none.ok()) << none.status();
    EXPECT_FALSE(none->has_value());
  }
  // Each sees the other's claim.
  absl::StatusOr<JobRecord> j1 = other->Get("j1");
  ASSERT_TRUE(j1.ok());
  EXPECT_EQ(j1->worker_id, "replica-a");
}

TEST_P(JobStoreTest, LapsedLeaseIsReclaimedAndOldWorkerLosesIt) {
  std::unique_ptr<JobStore> other = Reopen();
  ASSERT_NE(other, nullptr);
  CreateOrDie(*store_, "j", kT0);
  absl::StatusOr<std::optional<JobRecord>> a = store_->ClaimNext("old", kT0 + 10, 100);
  ASSERT_TRUE(a.ok() && a->has_value());
  ASSERT_EQ((*a)->lease_expiry, kT0 + 110);

  // Not yet lapsed: expiry must be strictly before now.
  absl::StatusOr<std::optional<JobRecord>> b = other->ClaimNext("new", kT0 + 110, 100);
  ASSERT_TRUE(b.ok()) << b.status();
  EXPECT_FALSE(b->has_value());

  b = other->ClaimNext("new", kT0 + 111, 100);
  ASSERT_TRUE(b.ok()) << b.status();
  ASSERT_TRUE(b->has_value());
  EXPECT_EQ((*b)->id, "j");
  EXPECT_EQ((*b)->worker_id, "new");
  EXPECT_EQ((*b)->attempts, 2u);
  EXPECT_EQ((*b)->start_time, kT0 + 111);
  EXPECT_EQ((*b)->lease_expiry, kT0 + 211);

  absl::StatusOr<bool> hb = store_->Heartbeat("j", "old", kT0 + 112, 100, 1, 2);
  EXPECT_EQ(hb.status().code(), absl::StatusCode::kFailedPrecondition) << hb.status();
  Completion done;
  absl::Status st = store_->Complete("j", "old", done, kT0 + 113);
  EXPECT_EQ(st.code(), absl::StatusCode::kFailedPrecondition) << st;
  EXPECT_EQ(store_->Release("j", "old").code(), absl::StatusCode::kFailedPrecondition);

  ASSERT_TRUE(other->Complete("j", "new", done, kT0 + 114).ok());
  absl::StatusOr<JobRecord> j = store_->Get("j");
  ASSERT_TRUE(j.ok());
  EXPECT_EQ(j->state, JobState::kSucceeded);
  // Finished jobs are no longer claimable and the old claim stays dead.
  EXPECT_EQ(store_->Heartbeat("j", "new", kT0 + 115, 100, 0, 0).status().code(),
            absl::StatusCode::kFailedPrecondition);
}

TEST_P(JobStoreTest, HeartbeatAndCompleteOnUnknownJobAreNotFound) {
  EXPECT_EQ(store_->Heartbeat("nope", "w", kT0, 100, 0, 0).status().code(),
            absl::StatusCode::kNotFound);
  EXPECT_EQ(store_->Complete("nope", "w", Completion{}, kT0).code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(store_->Release("nope", "w").code(), absl::StatusCode::kNotFound);
}

TEST_P(JobStoreTest, HeartbeatExtendsLeaseRecordsProgressAndReportsCancel) {
  CreateOrDie(*store_, "j", kT0);
  ASSERT_TRUE(store_->ClaimNext("w", kT0 + 1, 100).ok());
  absl::StatusOr<bool> hb = store_->Heartbeat("j", "w", kT0 + 50, 100, 3, 10);
  ASSERT_TRUE(hb.ok()) << hb.status();
  EXPECT_FALSE(*hb);
  absl::StatusOr<JobRecord> j = store_->Get("j");
  ASSERT_TRUE(j.ok());
  EXPECT_EQ(j->lease_expiry, kT0 + 150);
  EXPECT_EQ(j->progress_done, 3u);
  EXPECT_EQ(j->progress_total, 10u);
  // The extended lease keeps others away past the original expiry.
  absl::StatusOr<std::optional<JobRecord>> c = store_->ClaimNext("x", kT0 + 120, 100);
  ASSERT_TRUE(c.ok());
  EXPECT_FALSE(c->has_value());

  ASSERT_TRUE(store_->RequestCancel("j", kT0 + 60).ok());
  hb = store_->Heartbeat("j", "w", kT0 + 70, 100, 4, 10);
  ASSERT_TRUE(hb.ok()) << hb.status();
  EXPECT_TRUE(*hb);
}

TEST_P(JobStoreTest, CancelQueuedJobFinishesItAtOnce) {
  CreateOrDie(*store_, "j", kT0);
  absl::StatusOr<JobRecord> r = store_->RequestCancel("j", kT0 + 5);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_EQ(r->state, JobState::kCancelled);
  EXPECT_EQ(r->end_time, kT0 + 5);
  EXPECT_EQ(r->error, "cancelled by request");
  EXPECT_EQ(r->error_code, static_cast<int>(absl::StatusCode::kCancelled));
  absl::StatusOr<std::optional<JobRecord>> c = store_->ClaimNext("w", kT0 + 6, 100);
  ASSERT_TRUE(c.ok());
  EXPECT_FALSE(c->has_value());
}

TEST_P(JobStoreTest, CancelRunningJobOnlyFlagsIt) {
  CreateOrDie(*store_, "j", kT0);
  ASSERT_TRUE(store_->ClaimNext("w", kT0 + 1, 100).ok());
  absl::StatusOr<JobRecord> r = store_->RequestCancel("j", kT0 + 5);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_EQ(r->state, JobState::kRunning);
  EXPECT_TRUE(r->cancel_requested);
  EXPECT_EQ(r->worker_id, "w");
  EXPECT_EQ(r->end_time, 0);

  // The worker finishes the transition.
  Completion done;
  done.state = JobState::kCancelled;
  done.error = "cancelled by request";
  ASSERT_TRUE(store_->Complete("j", "w", done, kT0 + 9).ok());
  absl::StatusOr<JobRecord> j = store_->Get("j");
  ASSERT_TRUE(j.ok());
  EXPECT_EQ(j->state, JobState::kCancelled);
  EXPECT_EQ(j->end_time, kT0 + 9);
  EXPECT_EQ(j->worker_id, "");
}

TEST_P(JobStoreTest, CancelRequestedJobWithLapsedLeaseIsNeverReclaimed) {
  CreateOrDie(*store_, "j", kT0);
  ASSERT_TRUE(store_->ClaimNext("dead", kT0 + 1, 100).ok());
  ASSERT_TRUE(store_->RequestCancel("j", kT0 + 5).ok());
  absl::StatusOr<std::optional<JobRecord>> c = store_->ClaimNext("w", kT0 + 1000, 100);
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_FALSE(c->has_value());
  // Its worker is gone, so the store finishes the cancel itself.
  absl::StatusOr<JobRecord> j = store_->Get("j");
  ASSERT_TRUE(j.ok());
  EXPECT_EQ(j->state, JobState::kCancelled);
  EXPECT_EQ(j->end_time, kT0 + 1000);
  EXPECT_EQ(j->error_code, static_cast<int>(absl::StatusCode::kCancelled));
}

TEST_P(JobStoreTest, CancelFinishedJobLeavesItUnchanged) {
  CreateOrDie(*store_, "j", kT0);
  ASSERT_TRUE(store_->ClaimNext("w", kT0 + 1, 100).ok());
  Completion failed;
  failed.state = JobState::kFailed;
  failed.error = "diverged";
  ASSERT_TRUE(store_->Complete("j", "w", failed, kT0 + 2).ok());
  absl::StatusOr<JobRecord> before = store_->Get("j");
  ASSERT_TRUE(before.ok());
  absl::StatusOr<JobRecord> after = store_->RequestCancel("j", kT0 + 3);
  ASSERT_TRUE(after.ok()) << after.status();
  ExpectSameRecord(*after, *before);
  EXPECT_EQ(after->state, JobState::kFailed);
  EXPECT_FALSE(after->cancel_requested);
}

TEST_P(JobStoreTest, FailedJobKeepsItsStatusCodeAcrossReopen) {
  CreateOrDie(*store_, "j", kT0);
  ASSERT_TRUE(store_->ClaimNext("w", kT0 + 1, 100).ok());
  Completion failed;
  failed.state = JobState::kFailed;
  failed.error = "grid.resolution[0]: must be positive, got 0";
  failed.error_code = static_cast<int>(absl::StatusCode::kInvalidArgument);
  ASSERT_TRUE(store_->Complete("j", "w", failed, kT0 + 2).ok());
  store_.reset();
  store_ = Reopen();
  absl::StatusOr<JobRecord> j = store_->Get("j");
  ASSERT_TRUE(j.ok()) << j.status();
  EXPECT_EQ(j->state, JobState::kFailed);
  EXPECT_EQ(j->error, failed.error);
  EXPECT_EQ(j->error_code, 3);
}

TEST_P(JobStoreTest, CancelUnknownJobIsNotFound) {
  absl::StatusOr<JobRecord> r = store_->RequestCancel("ghost", kT0);
  EXPECT_EQ(r.status().code(), absl::StatusCode::kNotFound);
  EXPECT_NE(r.status().message().find("ghost"), std::string::npos);
}

TEST_P(JobStoreTest, CompleteRejectsNonTerminalState) {
  CreateOrDie(*store_, "j", kT0);
  ASSERT_TRUE(store_->ClaimNext("w", kT0 + 1, 100).ok());
  Completion c;
  c.state = JobState::kQueued;
  EXPECT_EQ(store_->Complete("j", "w", c, kT0 + 2).code(), absl::StatusCode::kInvalidArgument);
}

TEST_P(JobStoreTest, CompleteKeepsWarningsWhenNoneGiven) {
  NewJob job = MakeJob("j");
  job.warnings = "from submit";
  ASSERT_TRUE(store_->Create(job, kT0).ok());
  ASSERT_TRUE(store_->ClaimNext("w", kT0 + 1, 100).ok());
  ASSERT_TRUE(store_->Complete("j", "w", Completion{}, kT0 + 2).ok());
  absl::StatusOr<JobRecord> j = store_->Get("j");
  ASSERT_TRUE(j.ok());
  EXPECT_EQ(j->warnings, "from submit");
}

TEST_P(JobStoreTest, ReleaseRequeuesAndKeepsAttempts) {
  CreateOrDie(*store_, "j", kT0);
  ASSERT_TRUE(store_->ClaimNext("w", kT0 + 1, 100).ok());
  ASSERT_TRUE(store_->Release("j", "w").ok());
  absl::StatusOr<JobRecord> j = store_->Get("j");
  ASSERT_TRUE(j.ok());
  EXPECT_EQ(j->state, JobState::kQueued);
  EXPECT_EQ(j->worker_id, "");
  EXPECT_EQ(j->lease_expiry, 0);
  EXPECT_EQ(j->attempts, 1u);
  absl::StatusOr<std::optional<JobRecord>> c = store_->ClaimNext("w2", kT0 + 2, 100);
  ASSERT_TRUE(c.ok() && c->has_value());
  EXPECT_EQ((*c)->attempts, 2u);
}

TEST_P(JobStoreTest, PersistsAcrossReopen) {
  NewJob job = MakeJob("keep", "req-keep", "keep");
  job.progress_total = 9;
  ASSERT_TRUE(store_->Create(job, kT0).ok());
  CreateOrDie(*store_, "run", kT0 + 1);
  CreateOrDie(*store_, "wait", kT0 + 2);
  ASSERT_TRUE(store_->ClaimNext("w", kT0 + 3, 100).ok());  // keep
  ASSERT_TRUE(store_->ClaimNext("w", kT0 + 3, 100).ok());  // run
  ASSERT_TRUE(store_->Complete("keep", "w", Completion{}, kT0 + 4).ok());
  std::vector<JobRecord> before;
  for (const char* id : {"keep", "run", "wait"}) {
    absl::StatusOr<JobRecord> r = store_->Get(id);
    ASSERT_TRUE(r.ok());
    before.push_back(*r);
  }

  store_.reset();
  store_ = Reopen();
  ASSERT_NE(store_, nullptr);
  for (const JobRecord& b : before) {
    absl::StatusOr<JobRecord> r = store_->Get(b.id);
    ASSERT_TRUE(r.ok()) << r.status();
    ExpectSameRecord(*r, b);
  }
  // The idempotency index survives too.
  absl::StatusOr<JobRecord> again = store_->Create(MakeJob("other", "req-keep", "keep"), kT0 + 9);
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(again->id, "keep");
}

TEST_P(JobStoreTest, AcceptedJobSurvivesKillNine) {
  store_.reset();
  const pid_t pid = fork();
  ASSERT_GE(pid, 0);
  if (pid == 0) {
    // Child: accept a job and die without closing or checkpointing anything.
    absl::StatusOr<std::unique_ptr<JobStore>> s = where_.Open();
    if (!s.ok() || !(*s)->Create(MakeJob("survivor"), kT0).ok()) _exit(3);
    kill(getpid(), SIGKILL);
    _exit(4);
  }
  int status = 0;
  ASSERT_EQ(waitpid(pid, &status, 0), pid);
  ASSERT_TRUE(WIFSIGNALED(status)) << "child exited with " << WEXITSTATUS(status);
  EXPECT_EQ(WTERMSIG(status), SIGKILL);

  store_ = Reopen();
  ASSERT_NE(store_, nullptr);
  absl::StatusOr<JobRecord> r = store_->Get("survivor");
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_EQ(r->state, JobState::kQueued);
}

TEST_P(JobStoreTest, RequeueRunningPutsEveryRunningJobBack) {
  for (int i = 0; i < 4; ++i) CreateOrDie(*store_, "j" + std::to_string(i), kT0 + i);
  ASSERT_TRUE(store_->ClaimNext("w1", kT0 + 10, 100000).ok());  // j0
  ASSERT_TRUE(store_->ClaimNext("w2", kT0 + 10, 100000).ok());  // j1
  ASSERT_TRUE(store_->ClaimNext("w3", kT0 + 10, 100000).ok());  // j2
  ASSERT_TRUE(store_->Complete("j2", "w3", Completion{}, kT0 + 11).ok());

  absl::StatusOr<int> n = store_->RequeueRunning();
  ASSERT_TRUE(n.ok()) << n.status();
  EXPECT_EQ(*n, 2);
  for (const char* id : {"j0", "j1", "j3"}) {
    absl::StatusOr<JobRecord> r = store_->Get(id);
    ASSERT_TRUE(r.ok());
    EXPECT_EQ(r->state, JobState::kQueued) << id;
    EXPECT_EQ(r->worker_id, "") << id;
  }
  absl::StatusOr<JobRecord> j0 = store_->Get("j0");
  EXPECT_EQ(j0->attempts, 1u);
  absl::StatusOr<JobRecord> j2 = store_->Get("j2");
  EXPECT_EQ(j2->state, JobState::kSucceeded);

  // Requeued jobs are claimable again at once, oldest first.
  absl::StatusOr<std::optional<JobRecord>> c = store_->ClaimNext("w4", kT0 + 12, 100);
  ASSERT_TRUE(c.ok() && c->has_value());
  EXPECT_EQ((*c)->id, "j0");
  n = store_->RequeueRunning();
  ASSERT_TRUE(n.ok());
  EXPECT_EQ(*n, 1);
  n = store_->RequeueRunning();
  ASSERT_TRUE(n.ok());
  EXPECT_EQ(*n, 0);
}

TEST_P(JobStoreTest, CancelRequestedJobsAreCancelledNotRequeued) {
  // Requeued with cancel_requested set they could never be claimed again, so
  // both recovery paths finish the cancel instead.
  CreateOrDie(*store_, "released", kT0);
  CreateOrDie(*store_, "crashed", kT0 + 1);
  CreateOrDie(*store_, "plain", kT0 + 2);
  for (int i = 0; i < 3; ++i) ASSERT_TRUE(store_->ClaimNext("w", kT0 + 10, 100000).ok());
  ASSERT_TRUE(store_->RequestCancel("released", kT0 + 11).ok());
  ASSERT_TRUE(store_->RequestCancel("crashed", kT0 + 11).ok());

  ASSERT_TRUE(store_->Release("released", "w").ok());
  absl::StatusOr<int> n = store_->RequeueRunning();
  ASSERT_TRUE(n.ok()) << n.status();
  EXPECT_EQ(*n, 1);  // Only "plain".

  for (const char* id : {"released", "crashed"}) {
    absl::StatusOr<JobRecord> r = store_->Get(id);
    ASSERT_TRUE(r.ok());
    EXPECT_EQ(r->state, JobState::kCancelled) << id;
    EXPECT_EQ(r->error, "cancelled by request") << id;
    EXPECT_EQ(r->error_code, static_cast<int>(absl::StatusCode::kCancelled)) << id;
    EXPECT_EQ(r->worker_id, "") << id;
  }
  absl::StatusOr<JobRecord> crashed = store_->Get("crashed");
  EXPECT_GT(crashed->end_time, 0);
  absl::StatusOr<JobRecord> plain = store_->Get("plain");
  EXPECT_EQ(plain->state, JobState::kQueued);
}

// Claims `total` jobs with one thread per entry of `stores` and checks every
// job went to exactly one claimer.
void ClaimConcurrently(const std::vector<JobStore*>& stores, int total) {
  std::mutex mu;
  std::vector<std::string> claimed;
  std::vector<std::string> errors;
  std::vector<std::thread> threads;
  for (size_t t = 0; t < stores.size(); ++t) {
    threads.emplace_back([&, t] {
      const std::string worker = "worker-" + std::to_string(t);
      while (true) {
        absl::StatusOr<std::optional<JobRecord>> c = stores[t]->ClaimNext(worker, kT0 + 1, 60000);
        std::lock_guard<std::mutex> lock(mu);
        if (!c.ok()) {
          errors.push_back(c.status().ToString());
          return;
        }
        if (!c->has_value()) return;
        claimed.push_back((*c)->id);
      }
    });
  }
  for (std::thread& th : threads) th.join();
  EXPECT_TRUE(errors.empty()) << errors.front();
  EXPECT_EQ(claimed.size(), static_cast<size_t>(total));
  const std::set<std::string> unique(claimed.begin(), claimed.end());
  EXPECT_EQ(unique.size(), static_cast<size_t>(total));
}

TEST_P(JobStoreTest, ConcurrentClaimsFromFourThreadsClaimEachJobOnce) {
  constexpr int kJobs = 50;
  for (int i = 0; i < kJobs; ++i) CreateOrDie(*store_, "j" + std::to_string(i), kT0);
  ClaimConcurrently({store_.get(), store_.get(), store_.get(), store_.get()}, kJobs);
}

TEST_P(JobStoreTest, ConcurrentClaimsAcrossTwoConnectionsClaimEachJobOnce) {
  std::unique_ptr<JobStore> other = Reopen();
  ASSERT_NE(other, nullptr);
  constexpr int kJobs = 50;
  for (int i = 0; i < kJobs; ++i) CreateOrDie(*store_, "j" + std::to_string(i), kT0);
  ClaimConcurrently({store_.get(), other.get(), store_.get(), other.get()}, kJobs);
}

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
  const std::string top = plan(
      "SELECT priority FROM jobs INDEXED BY jobs_claim_order WHERE state = 1 AND "
      "cancel_requested = 0 AND shards_pending = 0 ORDER BY priority DESC LIMIT 1");
  EXPECT_NE(top.find("jobs_claim_order"), std::string::npos) << top;
  EXPECT_EQ(top.find("TEMP B-TREE"), std::string::npos) << top;
  const std::string seek = plan(
      "SELECT owner, create_time, rowid, id FROM jobs INDEXED BY jobs_claim_order WHERE "
      "state = 1 AND cancel_requested = 0 AND shards_pending = 0 AND priority = 50 AND "
      "owner > 'a' "
      "ORDER BY owner, create_time, rowid LIMIT 1");
  EXPECT_NE(seek.find("jobs_claim_order"), std::string::npos) << seek;
  EXPECT_EQ(seek.find("TEMP B-TREE"), std::string::npos) << seek;
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
  std::future<absl::StatusOr<JobRecord>> cancel = std::async(
      std::launch::async, [&] { return store_->RequestCancel("a", kT0 + 2); });
  // The write cannot finish while the lock is held; this also lets it reach
  // SQLite and wait there, holding the store's write mutex.
  EXPECT_EQ(cancel.wait_for(std::chrono::milliseconds(300)), std::future_status::timeout);
  for (int i = 0; i < 10; ++i) {
    const auto start = std::chrono::steady_clock::now();
    absl::StatusOr<JobRecord> b = store_->Get("b");
    absl::StatusOr<ListPage> page = store_->List({});
    const auto took = std::chrono::steady_clock::now() - start;
    ASSERT_TRUE(b.ok()) << b.status();
    ASSERT_TRUE(page.ok()) << page.status();
    EXPECT_EQ(page->jobs.size(), 2u);
    EXPECT_LT(took, std::chrono::milliseconds(100)) << "a read waited for the blocked write";
  }
  EXPECT_EQ(cancel.wait_for(std::chrono::seconds(0)), std::future_status::timeout);
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


// ---- Poison input: bounded text, byte-bounded pages, capped attempts ----

TEST_P(JobStoreTest, ErrorOfManyMegabytesIsStoredTruncated) {
  CreateOrDie(*store_, "big-error", kT0);
  ASSERT_TRUE(store_->ClaimNext("w", kT0 + 1, 1000).ok());
  Completion done;
  done.state = JobState::kFailed;
  done.error = std::string(8 << 20, 'x');
  done.error_code = static_cast<int>(absl::StatusCode::kInvalidArgument);
  ASSERT_TRUE(store_->Complete("big-error", "w", done, kT0 + 2).ok());
  absl::StatusOr<JobRecord> got = store_->Get("big-error");
  ASSERT_TRUE(got.ok()) << got.status();
  EXPECT_EQ(got->state, JobState::kFailed);
  EXPECT_LT(got->error.size(), 4200u);
  EXPECT_EQ(got->error.substr(0, 100), std::string(100, 'x'));
  EXPECT_NE(got->error.find("[truncated, 8388608 bytes]"), std::string::npos) << got->error;
}

TEST_P(JobStoreTest, HugeNameIsRefusedAndHugeIdIsNotEchoedWhole) {
  NewJob job = MakeJob("named");
  job.name = std::string(10 << 20, 'n');
  absl::StatusOr<JobRecord> r = store_->Create(job, kT0);
  ASSERT_EQ(r.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_LT(r.status().message().size(), 200u);
  EXPECT_NE(r.status().message().find("name"), absl::string_view::npos);
  EXPECT_EQ(store_->Get("named").status().code(), absl::StatusCode::kNotFound);

  absl::StatusOr<JobRecord> missing = store_->Get(std::string(100'000, 'i'));
  ASSERT_EQ(missing.status().code(), absl::StatusCode::kNotFound);
  EXPECT_LT(missing.status().message().size(), 200u);
}

TEST_P(JobStoreTest, ListPagesStayUnderTheByteBound) {
  // 400 failed jobs with errors of 1 MB each, stored as 4 KiB.
  for (int i = 0; i < 400; ++i) {
    const std::string id = "j" + std::to_string(1000 + i);
    CreateOrDie(*store_, id, kT0 + i);
    ASSERT_TRUE(store_->ClaimNext("w", kT0 + 1000, 100000).ok());
    Completion done;
    done.state = JobState::kFailed;
    done.error = std::string(1 << 20, 'e');
    ASSERT_TRUE(store_->Complete(id, "w", done, kT0 + 1001).ok());
  }
  ListOptions o;
  o.page_size = 500;
  o.max_bytes = 256 << 10;
  std::set<std::string> seen;
  int pages = 0;
  while (true) {
    absl::StatusOr<ListPage> page = store_->List(o);
    ASSERT_TRUE(page.ok()) << page.status();
    ++pages;
    uint64_t bytes = 0;
    for (const JobRecord& j : page->jobs) {
      bytes += j.id.size() + j.name.size() + 2 * j.error.size() + j.warnings.size();
      EXPECT_TRUE(seen.insert(j.id).second) << j.id;
    }
    EXPECT_LE(bytes, o.max_bytes);
    EXPECT_FALSE(page->jobs.empty());
    if (page->next_page_token.empty()) break;
    o.page_token = page->next_page_token;
  }
  EXPECT_EQ(seen.size(), 400u);
  EXPECT_GT(pages, 2);
}

TEST_P(JobStoreTest, AbandonedAttemptsEndFailedWithTheLastError) {
  CreateOrDie(*store_, "poison", kT0);
  CreateOrDie(*store_, "fine", kT0 + 1);
  for (int attempt = 1; attempt <= 3; ++attempt) {
    absl::StatusOr<std::optional<JobRecord>> c = store_->ClaimNext("w", kT0 + 10, 1000, 3);
    ASSERT_TRUE(c.ok() && c->has_value()) << c.status();
    ASSERT_EQ((*c)->id, "poison");
    EXPECT_EQ((*c)->attempts, static_cast<uint32_t>(attempt));
    ASSERT_TRUE(store_->AbandonAttempt("poison", "w",
                                       "could not record the end, attempt " +
                                           std::to_string(attempt),
                                       static_cast<int>(absl::StatusCode::kInternal))
                    .ok());
    EXPECT_EQ(store_->Get("poison")->state, JobState::kQueued);
  }
  // The fourth claim gives the poison job up and hands out the next one.
  std::vector<JobRecord> given_up;
  absl::StatusOr<std::optional<JobRecord>> c =
      store_->ClaimNext("w", kT0 + 20, 1000, 3, &given_up);
  ASSERT_TRUE(c.ok() && c->has_value()) << c.status();
  EXPECT_EQ((*c)->id, "fine");
  ASSERT_EQ(given_up.size(), 1u);
  EXPECT_EQ(given_up[0].id, "poison");
  absl::StatusOr<JobRecord> poison = store_->Get("poison");
  ASSERT_TRUE(poison.ok());
  EXPECT_EQ(poison->state, JobState::kFailed);
  EXPECT_EQ(poison->attempts, 3u);
  EXPECT_EQ(poison->error,
            "gave up after 3 attempts; the last one: could not record the end, attempt 3");
  EXPECT_EQ(poison->error_code, static_cast<int>(absl::StatusCode::kInternal));
}

TEST_P(JobStoreTest, LapsedLeasesCountAsAttempts) {
  CreateOrDie(*store_, "crashy", kT0);
  for (int attempt = 1; attempt <= 2; ++attempt) {
    absl::StatusOr<std::optional<JobRecord>> c =
        store_->ClaimNext("w", kT0 + attempt * 1000, 100, 2);
    ASSERT_TRUE(c.ok() && c->has_value()) << c.status();
  }
  absl::StatusOr<std::optional<JobRecord>> c = store_->ClaimNext("w", kT0 + 5000, 100, 2);
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_FALSE(c->has_value());
  absl::StatusOr<JobRecord> got = store_->Get("crashy");
  ASSERT_TRUE(got.ok());
  EXPECT_EQ(got->state, JobState::kFailed);
  EXPECT_NE(got->error.find("gave up after 2 attempts: none recorded an end"),
            std::string::npos)
      << got->error;
}

}  // namespace
}  // namespace nimbus::server

namespace nimbus::server {
namespace {

PokeRecord Push(int32_t body, double x) {
  PokeRecord p;
  p.body = body;
  p.x = x;
  return p;
}

TEST_P(JobStoreTest, PokesNeedARunningJob) {
  EXPECT_EQ(store_->AddPoke("nope", Push(0, 1)).status().code(), absl::StatusCode::kNotFound);
  CreateOrDie(*store_, "a", kT0);
  auto queued = store_->AddPoke("a", Push(0, 1));
  EXPECT_EQ(queued.status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_NE(queued.status().message().find("QUEUED"), std::string::npos);
  ASSERT_TRUE(store_->ClaimNext("w", kT0, 1000).ok());
  auto ok = store_->AddPoke("a", Push(0, 1));
  ASSERT_TRUE(ok.ok()) << ok.status();
  EXPECT_EQ(ok->frame, -1);
  EXPECT_GT(ok->seq, 0);
}

TEST_P(JobStoreTest, TakingPokesFixesTheirFrameForEveryLaterAttempt) {
  CreateOrDie(*store_, "a", kT0);
  ASSERT_TRUE(store_->ClaimNext("w1", kT0, 1000).ok());
  PokeRecord drag = Push(2, 0.5);
  drag.drag = true;
  drag.y = -1;
  drag.z = 2;
  drag.drag_stiffness = 80;
  drag.drag_frames = 3;
  ASSERT_TRUE(store_->AddPoke("a", Push(1, 3)).ok());
  ASSERT_TRUE(store_->AddPoke("a", drag).ok());
  // Another worker cannot take them.
  EXPECT_EQ(store_->TakePokes("a", "intruder", 4).status().code(),
            absl::StatusCode::kFailedPrecondition);
  auto at4 = store_->TakePokes("a", "w1", 4);
  ASSERT_TRUE(at4.ok()) << at4.status();
  ASSERT_EQ(at4->size(), 2u);
  EXPECT_EQ((*at4)[0].body, 1);
  EXPECT_EQ((*at4)[0].x, 3);
  EXPECT_EQ((*at4)[0].frame, 4);
  const PokeRecord& d = (*at4)[1];
  EXPECT_TRUE(d.drag);
  EXPECT_EQ(d.body, 2);
  EXPECT_EQ(d.x, 0.5);
  EXPECT_EQ(d.y, -1);
  EXPECT_EQ(d.z, 2);
  EXPECT_EQ(d.drag_stiffness, 80);
  EXPECT_EQ(d.drag_frames, 3u);
  EXPECT_LT((*at4)[0].seq, d.seq);
  EXPECT_TRUE(store_->TakePokes("a", "w1", 5)->empty());
  // A later poke goes to the next frame taken; the job restarts and a new
  // attempt sees each poke at its own frame again.
  ASSERT_TRUE(store_->AddPoke("a", Push(0, 7)).ok());
  ASSERT_EQ(store_->TakePokes("a", "w1", 6)->size(), 1u);
  ASSERT_TRUE(store_->Release("a", "w1").ok());
  ASSERT_TRUE(store_->ClaimNext("w2", kT0 + 1, 1000).ok());
  EXPECT_EQ(store_->TakePokes("a", "w2", 4)->size(), 2u);
  EXPECT_TRUE(store_->TakePokes("a", "w2", 5)->empty());
  auto at6 = store_->TakePokes("a", "w2", 6);
  ASSERT_EQ(at6->size(), 1u);
  EXPECT_EQ((*at6)[0].x, 7);
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
  EXPECT_EQ(QueryInt(path, "SELECT count(*) FROM jobs WHERE parent_id <> '' OR shard_count <> 0 "
                           "OR spec_sha256 <> '' OR cached_from <> ''"),
            0);
  EXPECT_EQ(store->Get("failed")->error, "diverged");
  ASSERT_TRUE(store->ClaimNext("w", kT0, 100).ok());
  EXPECT_TRUE(store->AddPoke("queued", Push(0, 1)).ok());
}

}  // namespace
}  // namespace nimbus::server
