// A job whose end cannot be recorded does not loop: the worker retries the
// completion once with a short error, then abandons the attempt with its
// reason, and the store fails the job once its attempts run out. The
// worker keeps serving other jobs throughout.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <mutex>

#include "server/job_hub.h"
#include "server/job_store.h"
#include "server/job_view.h"
#include "server/result_store.h"
#include "server/worker_pool.h"
#include "tests/support/test_util.h"

namespace nimbus::server {
namespace {

// The real SQLite store, except that every Complete fails the way an
// oversized write would.
class CompleteFailsStore final : public JobStore {
 public:
  explicit CompleteFailsStore(std::unique_ptr<JobStore> inner) : inner_(std::move(inner)) {}
  absl::StatusOr<JobRecord> Create(const NewJob& job, TimeMs now) override {
    return inner_->Create(job, now);
  }
  absl::StatusOr<JobRecord> Get(const std::string& id) override { return inner_->Get(id); }
  absl::StatusOr<ListPage> List(const ListOptions& o) override { return inner_->List(o); }
  absl::StatusOr<std::optional<JobRecord>> ClaimNext(const std::string& w, TimeMs now, TimeMs lease,
                                                     uint32_t max_attempts,
                                                     std::vector<JobRecord>* given_up) override {
    return inner_->ClaimNext(w, now, lease, max_attempts, given_up);
  }
  absl::StatusOr<bool> Heartbeat(const std::string& id, const std::string& w, TimeMs now,
                                 TimeMs lease, uint64_t done, uint64_t total) override {
    return inner_->Heartbeat(id, w, now, lease, done, total);
  }
  absl::Status Complete(const std::string&, const std::string&, const Completion&,
                        TimeMs) override {
    ++completes;
    return absl::ResourceExhaustedError(std::string(2 << 20, 'm'));
  }
  absl::Status AbandonAttempt(const std::string& id, const std::string& w, const std::string& error,
                              int code) override {
    return inner_->AbandonAttempt(id, w, error, code);
  }
  absl::Status Release(const std::string& id, const std::string& w) override {
    return inner_->Release(id, w);
  }
  absl::StatusOr<JobRecord> RequestCancel(const std::string& id, TimeMs now,
                                          const std::string& by) override {
    return inner_->RequestCancel(id, now, by);
  }
  absl::StatusOr<int> RequeueRunning() override { return inner_->RequeueRunning(); }
  absl::StatusOr<OwnerUsage> Usage(const std::string& owner) override {
    return inner_->Usage(owner);
  }
  absl::StatusOr<JobRecord> SetPinned(const std::string& id, bool pinned) override {
    return inner_->SetPinned(id, pinned);
  }
  absl::Status Delete(const std::string& id) override { return inner_->Delete(id); }
  absl::StatusOr<std::vector<JobRecord>> ListExpiring(TimeMs cutoff, int limit) override {
    return inner_->ListExpiring(cutoff, limit);
  }
  absl::Status MarkResultExpired(const std::string& id, TimeMs now) override {
    return inner_->MarkResultExpired(id, now);
  }
  absl::StatusOr<std::vector<std::string>> SpecsInUse() override { return inner_->SpecsInUse(); }
  absl::StatusOr<PokeRecord> AddPoke(const std::string& id, const PokeRecord& p) override {
    return inner_->AddPoke(id, p);
  }
  absl::StatusOr<std::vector<PokeRecord>> TakePokes(const std::string& id, const std::string& w,
                                                    int64_t frame) override {
    return inner_->TakePokes(id, w, frame);
  }
  absl::StatusOr<std::vector<JobRecord>> ListShards(const std::string& parent) override {
    return inner_->ListShards(parent);
  }
  absl::StatusOr<std::optional<JobRecord>> FindCached(const std::string& sha,
                                                      const std::string& owner) override {
    return inner_->FindCached(sha, owner);
  }

  std::atomic<int> completes{0};

 private:
  std::unique_ptr<JobStore> inner_;
};

TEST(WorkerPoison, AJobThatCannotRecordItsEndFailsAfterTheCap) {
  testing::TempDir dir;
  auto sqlite = OpenSqliteJobStore((dir / "jobs.db").string());
  ASSERT_TRUE(sqlite.ok()) << sqlite.status();
  CompleteFailsStore store(std::move(*sqlite));
  auto results = OpenLocalResultStore(dir / "results");
  ASSERT_TRUE(results.ok()) << results.status();
  JobHub hub;

  // An unreadable stored spec: each attempt fails at once, and its failure
  // cannot be recorded.
  NewJob job;
  job.id = "poison";
  job.name = "poison";
  job.spec = "\xff\xff\xff not a spec";
  ASSERT_TRUE(store.Create(job, NowMs()).ok());

  std::mutex mu;
  std::condition_variable cv;
  std::optional<v1::Job> ended;
  const uint64_t sub = hub.Subscribe("poison", 0, 0, [&](const JobSnapshot& s) {
    if (!s.job || s.job->state() != v1::JOB_STATE_FAILED) return;
    std::lock_guard<std::mutex> lock(mu);
    ended = *s.job;
    cv.notify_all();
  });

  WorkerOptions options;
  options.workers = 1;
  options.threads_per_job = 1;
  options.max_attempts = 3;
  WorkerPool pool(&store, results->get(), &hub, options);
  pool.Start();
  pool.Wake();
  {
    std::unique_lock<std::mutex> lock(mu);
    ASSERT_TRUE(cv.wait_for(lock, std::chrono::seconds(60), [&] { return ended.has_value(); }))
        << "the job never ended";
  }
  hub.Unsubscribe("poison", sub);
  pool.Stop();

  absl::StatusOr<JobRecord> rec = store.Get("poison");
  ASSERT_TRUE(rec.ok()) << rec.status();
  EXPECT_EQ(rec->state, JobState::kFailed);
  EXPECT_EQ(rec->attempts, 3u);
  EXPECT_THAT(rec->error, ::testing::StartsWith("gave up after 3 attempts; the last one: could "
                                                "not record the job's end ("));
  EXPECT_THAT(rec->error, ::testing::HasSubstr("the stored spec is unreadable"));
  EXPECT_LT(rec->error.size(), 1024u);
  EXPECT_EQ(rec->error_code, static_cast<int>(absl::StatusCode::kDataLoss));
  // Two tries per attempt: the full completion, then the short one.
  EXPECT_EQ(store.completes.load(), 6);
  EXPECT_EQ(ended->attempts(), 3u);
}

}  // namespace
}  // namespace nimbus::server
