// The queue's contract (JobQueue in server/job_store.h): create, get, list,
// claim, lease, complete and cancel, the same on every store kind.
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <mutex>
#include <optional>
#include <set>
#include <thread>

#include "absl/status/status.h"
#include "server/job_store.h"
#include "tests/support/job_store_contract.h"

namespace nimbus::server {
namespace {

using namespace contract;  // NOLINT: the contract's helpers

NIMBUS_STORE_CONTRACT_SUITE(JobQueueTest);

TEST_P(JobQueueTest, CreateAndGetRoundTripEveryField) {
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
  ASSERT_TRUE(store_->RequestCancel("job-1", kT0 + 15, "ann").ok());
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

TEST_P(JobQueueTest, EmptySpecAndStringsRoundTrip) {
  NewJob job;
  job.id = "bare";
  ASSERT_TRUE(store_->Create(job, kT0).ok());
  absl::StatusOr<JobRecord> got = store_->Get("bare");
  ASSERT_TRUE(got.ok()) << got.status();
  EXPECT_EQ(got->spec, "");
  EXPECT_EQ(got->name, "");
  EXPECT_EQ(got->request_id, "");
}

TEST_P(JobQueueTest, GetUnknownIsNotFoundNamingTheId) {
  absl::StatusOr<JobRecord> got = store_->Get("no-such-job");
  EXPECT_EQ(got.status().code(), absl::StatusCode::kNotFound);
  EXPECT_NE(got.status().message().find("no-such-job"), std::string::npos) << got.status();
}

TEST_P(JobQueueTest, CreateIsIdempotentByRequestId) {
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
TEST_P(JobQueueTest, RequestIdsArePerPrincipal) {
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

TEST_P(JobQueueTest, DuplicateIdIsAlreadyExists) {
  ASSERT_TRUE(store_->Create(MakeJob("a"), kT0).ok());
  absl::StatusOr<JobRecord> dup = store_->Create(MakeJob("a"), kT0 + 1);
  EXPECT_EQ(dup.status().code(), absl::StatusCode::kAlreadyExists) << dup.status();
  // The failed insert rolled back; the store is still usable.
  EXPECT_TRUE(store_->Create(MakeJob("b"), kT0 + 2).ok());
}

TEST_P(JobQueueTest, ListIsNewestFirstWithIdTieBreak) {
  CreateOrDie(*store_, "x", kT0 + 1);
  CreateOrDie(*store_, "b", kT0 + 2);
  CreateOrDie(*store_, "c", kT0 + 2);
  CreateOrDie(*store_, "a", kT0 + 3);
  absl::StatusOr<ListPage> page = store_->List({});
  ASSERT_TRUE(page.ok()) << page.status();
  EXPECT_EQ(Ids(page->jobs), (std::vector<std::string>{"a", "c", "b", "x"}));
  EXPECT_EQ(page->next_page_token, "");
}

TEST_P(JobQueueTest, ListPagesThroughSevenJobs) {
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

TEST_P(JobQueueTest, PageTokenStaysValidWhileNewJobsArrive) {
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

TEST_P(JobQueueTest, ListFiltersByState) {
  for (int i = 0; i < 5; ++i) CreateOrDie(*store_, "j" + std::to_string(i), kT0 + i);
  absl::StatusOr<std::optional<JobRecord>> claimed = store_->ClaimNext("w", kT0 + 10, 1000);
  ASSERT_TRUE(claimed.ok() && claimed->has_value());  // j0
  ASSERT_TRUE(store_->RequestCancel("j3", kT0 + 11, "ann").ok());

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

TEST_P(JobQueueTest, ListClampsPageSize) {
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

TEST_P(JobQueueTest, ListRejectsGarbageToken) {
  ListOptions options;
  options.page_token = "not a token!";
  EXPECT_EQ(store_->List(options).status().code(), absl::StatusCode::kInvalidArgument);
  options.page_token = "bm9jb2xvbg";  // base64 of "nocolon"
  EXPECT_EQ(store_->List(options).status().code(), absl::StatusCode::kInvalidArgument);
}

TEST_P(JobQueueTest, ClaimTakesOldestFirst) {
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

TEST_P(JobQueueTest, TwoStoresOnOneFileNeverDoubleClaim) {
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

TEST_P(JobQueueTest, LapsedLeaseIsReclaimedAndOldWorkerLosesIt) {
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

TEST_P(JobQueueTest, HeartbeatAndCompleteOnUnknownJobAreNotFound) {
  EXPECT_EQ(store_->Heartbeat("nope", "w", kT0, 100, 0, 0).status().code(),
            absl::StatusCode::kNotFound);
  EXPECT_EQ(store_->Complete("nope", "w", Completion{}, kT0).code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(store_->Release("nope", "w").code(), absl::StatusCode::kNotFound);
}

TEST_P(JobQueueTest, HeartbeatExtendsLeaseRecordsProgressAndReportsCancel) {
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

  ASSERT_TRUE(store_->RequestCancel("j", kT0 + 60, "ann").ok());
  hb = store_->Heartbeat("j", "w", kT0 + 70, 100, 4, 10);
  ASSERT_TRUE(hb.ok()) << hb.status();
  EXPECT_TRUE(*hb);
}

TEST_P(JobQueueTest, CancelQueuedJobFinishesItAtOnce) {
  CreateOrDie(*store_, "j", kT0);
  absl::StatusOr<JobRecord> r = store_->RequestCancel("j", kT0 + 5, "ann");
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_EQ(r->state, JobState::kCancelled);
  EXPECT_EQ(r->end_time, kT0 + 5);
  EXPECT_EQ(r->error, "cancelled by request");
  EXPECT_EQ(r->error_code, static_cast<int>(absl::StatusCode::kCancelled));
  absl::StatusOr<std::optional<JobRecord>> c = store_->ClaimNext("w", kT0 + 6, 100);
  ASSERT_TRUE(c.ok());
  EXPECT_FALSE(c->has_value());
}

TEST_P(JobQueueTest, CancelRunningJobOnlyFlagsIt) {
  CreateOrDie(*store_, "j", kT0);
  ASSERT_TRUE(store_->ClaimNext("w", kT0 + 1, 100).ok());
  absl::StatusOr<JobRecord> r = store_->RequestCancel("j", kT0 + 5, "ann");
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

TEST_P(JobQueueTest, CancelRequestedJobWithLapsedLeaseIsNeverReclaimed) {
  CreateOrDie(*store_, "j", kT0);
  ASSERT_TRUE(store_->ClaimNext("dead", kT0 + 1, 100).ok());
  ASSERT_TRUE(store_->RequestCancel("j", kT0 + 5, "ann").ok());
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

TEST_P(JobQueueTest, CancelFinishedJobLeavesItUnchanged) {
  CreateOrDie(*store_, "j", kT0);
  ASSERT_TRUE(store_->ClaimNext("w", kT0 + 1, 100).ok());
  Completion failed;
  failed.state = JobState::kFailed;
  failed.error = "diverged";
  ASSERT_TRUE(store_->Complete("j", "w", failed, kT0 + 2).ok());
  absl::StatusOr<JobRecord> before = store_->Get("j");
  ASSERT_TRUE(before.ok());
  absl::StatusOr<JobRecord> after = store_->RequestCancel("j", kT0 + 3, "ann");
  ASSERT_TRUE(after.ok()) << after.status();
  ExpectSameRecord(*after, *before);
  EXPECT_EQ(after->state, JobState::kFailed);
  EXPECT_FALSE(after->cancel_requested);
}

TEST_P(JobQueueTest, FailedJobKeepsItsStatusCodeAcrossReopen) {
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

TEST_P(JobQueueTest, CancelUnknownJobIsNotFound) {
  absl::StatusOr<JobRecord> r = store_->RequestCancel("ghost", kT0, "ann");
  EXPECT_EQ(r.status().code(), absl::StatusCode::kNotFound);
  EXPECT_NE(r.status().message().find("ghost"), std::string::npos);
}

TEST_P(JobQueueTest, CompleteRejectsNonTerminalState) {
  CreateOrDie(*store_, "j", kT0);
  ASSERT_TRUE(store_->ClaimNext("w", kT0 + 1, 100).ok());
  Completion c;
  c.state = JobState::kQueued;
  EXPECT_EQ(store_->Complete("j", "w", c, kT0 + 2).code(), absl::StatusCode::kInvalidArgument);
}

TEST_P(JobQueueTest, CompleteKeepsWarningsWhenNoneGiven) {
  NewJob job = MakeJob("j");
  job.warnings = "from submit";
  ASSERT_TRUE(store_->Create(job, kT0).ok());
  ASSERT_TRUE(store_->ClaimNext("w", kT0 + 1, 100).ok());
  ASSERT_TRUE(store_->Complete("j", "w", Completion{}, kT0 + 2).ok());
  absl::StatusOr<JobRecord> j = store_->Get("j");
  ASSERT_TRUE(j.ok());
  EXPECT_EQ(j->warnings, "from submit");
}

TEST_P(JobQueueTest, ReleaseRequeuesAndKeepsAttempts) {
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

TEST_P(JobQueueTest, PersistsAcrossReopen) {
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

TEST_P(JobQueueTest, AcceptedJobSurvivesKillNine) {
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

TEST_P(JobQueueTest, RequeueRunningPutsEveryRunningJobBack) {
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

TEST_P(JobQueueTest, CancelRequestedJobsAreCancelledNotRequeued) {
  // Requeued with cancel_requested set they could never be claimed again, so
  // both recovery paths finish the cancel instead.
  CreateOrDie(*store_, "released", kT0);
  CreateOrDie(*store_, "crashed", kT0 + 1);
  CreateOrDie(*store_, "plain", kT0 + 2);
  for (int i = 0; i < 3; ++i) ASSERT_TRUE(store_->ClaimNext("w", kT0 + 10, 100000).ok());
  ASSERT_TRUE(store_->RequestCancel("released", kT0 + 11, "ann").ok());
  ASSERT_TRUE(store_->RequestCancel("crashed", kT0 + 11, "ann").ok());

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

TEST_P(JobQueueTest, ConcurrentClaimsFromFourThreadsClaimEachJobOnce) {
  constexpr int kJobs = 50;
  for (int i = 0; i < kJobs; ++i) CreateOrDie(*store_, "j" + std::to_string(i), kT0);
  ClaimConcurrently({store_.get(), store_.get(), store_.get(), store_.get()}, kJobs);
}

TEST_P(JobQueueTest, ConcurrentClaimsAcrossTwoConnectionsClaimEachJobOnce) {
  std::unique_ptr<JobStore> other = Reopen();
  ASSERT_NE(other, nullptr);
  constexpr int kJobs = 50;
  for (int i = 0; i < kJobs; ++i) CreateOrDie(*store_, "j" + std::to_string(i), kT0);
  ClaimConcurrently({store_.get(), other.get(), store_.get(), other.get()}, kJobs);
}

TEST_P(JobQueueTest, ErrorOfManyMegabytesIsStoredTruncated) {
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

TEST_P(JobQueueTest, HugeNameIsRefusedAndHugeIdIsNotEchoedWhole) {
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

TEST_P(JobQueueTest, ListPagesStayUnderTheByteBound) {
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

TEST_P(JobQueueTest, AbandonedAttemptsEndFailedWithTheLastError) {
  CreateOrDie(*store_, "poison", kT0);
  CreateOrDie(*store_, "fine", kT0 + 1);
  for (int attempt = 1; attempt <= 3; ++attempt) {
    absl::StatusOr<std::optional<JobRecord>> c = store_->ClaimNext("w", kT0 + 10, 1000, 3);
    ASSERT_TRUE(c.ok() && c->has_value()) << c.status();
    ASSERT_EQ((*c)->id, "poison");
    EXPECT_EQ((*c)->attempts, static_cast<uint32_t>(attempt));
    ASSERT_TRUE(store_
                    ->AbandonAttempt("poison", "w",
                                     "could not record the end, attempt " + std::to_string(attempt),
                                     static_cast<int>(absl::StatusCode::kInternal))
                    .ok());
    EXPECT_EQ(store_->Get("poison")->state, JobState::kQueued);
  }
  // The fourth claim gives the poison job up and hands out the next one.
  std::vector<JobRecord> given_up;
  absl::StatusOr<std::optional<JobRecord>> c = store_->ClaimNext("w", kT0 + 20, 1000, 3, &given_up);
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

TEST_P(JobQueueTest, LapsedLeasesCountAsAttempts) {
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
  EXPECT_NE(got->error.find("gave up after 2 attempts: none recorded an end"), std::string::npos)
      << got->error;
}

}  // namespace
}  // namespace nimbus::server
