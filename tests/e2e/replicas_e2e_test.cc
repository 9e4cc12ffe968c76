// Several nimbusd replicas on one PostgreSQL queue and one shared results
// folder: every job completes exactly once, a replica killed mid-job is
// replaced by another that finishes it byte-identically, and a watcher on
// one replica follows a job another runs. Short leases keep failover fast.
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/str_join.h"
#include "client/nimbus_client.h"
#include "core/base/sha256.h"
#include "nimbus/v1/nimbus_service.grpc.pb.h"
#include "proto/spec_io.h"
#include "tests/support/job_store_factory.h"
#include "tests/support/nimbusd_process.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

using client::NimbusClient;
using Clock = std::chrono::steady_clock;

constexpr int kReplicas = 3;

v1::JobSpec Tetrahedron(int resolution, uint64_t iterations) {
  auto spec = spec::LoadSpecFile(testing::SourcePath("examples/sierpinski_tetrahedron.json"));
  EXPECT_TRUE(spec.ok());
  spec->mutable_grid()->set_resolution(0, resolution);
  spec->mutable_chaos_game()->set_iterations(iterations);
  // Every job here must really run, never be answered from the result cache.
  spec->set_no_cache(true);
  return *spec;
}

std::string ReadText(const std::filesystem::path& path) {
  std::ifstream in(path);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

size_t CountOf(const std::string& text, const std::string& needle) {
  size_t n = 0;
  for (size_t at = text.find(needle); at != std::string::npos; at = text.find(needle, at + 1)) ++n;
  return n;
}

class ReplicasE2E : public ::testing::Test {
 protected:
  void SetUp() override {
    absl::StatusOr<std::string> url = testing::FreshPostgresUrl();
    if (absl::IsUnavailable(url.status())) GTEST_SKIP() << url.status().message();
    ASSERT_TRUE(url.ok()) << url.status();
    url_ = *url;
    for (int i = 0; i < kReplicas; ++i) {
      replicas_.push_back(std::make_unique<testing::NimbusdProcess>(
          dir_ / ("data-" + std::to_string(i)), Args(i)));
      replicas_.back()->set_log_file(LogPath(i));
      ASSERT_TRUE(replicas_.back()->Start().ok());
      clients_.push_back(NimbusClient::Connect(replicas_.back()->target()));
      ASSERT_TRUE(clients_.back()->WaitForReady(20).ok());
    }
  }

  std::vector<std::string> Args(int i) const {
    return {"--store", url_, "--results-dir", (dir_ / "results").string(), "--replica-id",
            ReplicaId(i), "--workers", "2", "--threads-per-job", "1", "--lease-ms", "1500",
            "--heartbeat-ms", "250", "--min-free-disk-mib", "0", "--log-level", "info"};
  }
  static std::string ReplicaId(int i) { return "replica" + std::to_string(i); }
  std::filesystem::path LogPath(int i) const {
    return dir_ / ("replica-" + std::to_string(i) + ".log");
  }

  // Waits until `id` ends (polling any live replica); its final view.
  v1::Job AwaitEnd(const std::string& id, NimbusClient& client, int seconds = 120) {
    const auto deadline = Clock::now() + std::chrono::seconds(seconds);
    v1::Job job;
    while (Clock::now() < deadline) {
      auto got = client.Get(id);
      if (got.ok()) {
        job = *got;
        if (job.state() == v1::JOB_STATE_SUCCEEDED || job.state() == v1::JOB_STATE_FAILED ||
            job.state() == v1::JOB_STATE_CANCELLED)
          return job;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
    ADD_FAILURE() << "job " << id << " did not end; last state "
                  << v1::JobState_Name(job.state());
    return job;
  }

  // Waits until `id` runs with some progress; the replica index running it.
  int AwaitRunningWithProgress(const std::string& id, NimbusClient& client) {
    const auto deadline = Clock::now() + std::chrono::seconds(60);
    while (Clock::now() < deadline) {
      auto got = client.Get(id);
      if (got.ok() &&
          (got->state() == v1::JOB_STATE_SUCCEEDED || got->state() == v1::JOB_STATE_FAILED ||
           got->state() == v1::JOB_STATE_CANCELLED)) {
        // Progress reaches another replica's view with the runner's
        // heartbeats: a job shorter than one is never seen running there.
        ADD_FAILURE() << "job " << id << " ended (" << v1::JobState_Name(got->state())
                      << ") before it was seen running with progress: too short";
        return -1;
      }
      if (got.ok() && got->state() == v1::JOB_STATE_RUNNING && got->progress().done() > 0) {
        for (int i = 0; i < kReplicas; ++i)
          if (got->worker().rfind(ReplicaId(i) + "/", 0) == 0) return i;
        ADD_FAILURE() << "unknown worker " << got->worker();
        return -1;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    ADD_FAILURE() << "job " << id << " never ran";
    return -1;
  }

  std::string FetchSha(NimbusClient& client, const std::string& id, const std::string& name) {
    const auto path = dir_ / name;
    auto st = client.Fetch(id, path);
    EXPECT_TRUE(st.ok()) << st;
    auto sha = Sha256File(path);
    return sha.ok() ? *sha : "";
  }

  testing::TempDir dir_;
  std::string url_;
  std::vector<std::unique_ptr<testing::NimbusdProcess>> replicas_;
  std::vector<std::unique_ptr<NimbusClient>> clients_;
};

TEST_F(ReplicasE2E, TwoHundredJobsFromParallelClientsEachCompleteExactlyOnce) {
  constexpr int kThreads = 4, kPerThread = 50;
  const v1::JobSpec spec = Tetrahedron(16, 20'000);
  std::mutex mu;
  std::vector<std::string> ids;
  std::vector<std::string> errors;
  std::vector<std::thread> threads;
  for (int t = 0; t < kThreads; ++t) {
    threads.emplace_back([&, t] {
      // A client of its own per thread, spread over the replicas.
      std::vector<std::unique_ptr<NimbusClient>> mine;
      for (int i = 0; i < kReplicas; ++i)
        mine.push_back(NimbusClient::Connect(replicas_[i]->target()));
      for (int k = 0; k < kPerThread; ++k) {
        // Every third submit is retried with the same request id on
        // another replica: idempotency holds across replicas.
        const std::string request = "req-" + std::to_string(t) + "-" + std::to_string(k);
        auto job = mine[(t + k) % kReplicas]->Submit(spec, request);
        if (job.ok() && k % 3 == 0) {
          auto again = mine[(t + k + 1) % kReplicas]->Submit(spec, request);
          std::lock_guard<std::mutex> lock(mu);
          if (!again.ok() || again->id() != job->id())
            errors.push_back("retry of " + request + " made another job");
        }
        std::lock_guard<std::mutex> lock(mu);
        if (job.ok())
          ids.push_back(job->id());
        else
          errors.push_back(job.status().ToString());
      }
    });
  }
  for (auto& th : threads) th.join();
  ASSERT_TRUE(errors.empty()) << errors.front();
  ASSERT_EQ(std::set<std::string>(ids.begin(), ids.end()).size(), size_t(kThreads * kPerThread));

  // All of them end SUCCEEDED after one attempt, with the same bytes.
  std::set<std::string> shas;
  for (size_t i = 0; i < ids.size(); ++i) {
    const v1::Job job = AwaitEnd(ids[i], *clients_[i % kReplicas]);
    ASSERT_EQ(job.state(), v1::JOB_STATE_SUCCEEDED) << ids[i] << ": " << job.error();
    EXPECT_EQ(job.attempts(), 1u) << ids[i];
    shas.insert(job.result().sha256());
  }
  EXPECT_EQ(shas.size(), 1u);
  // Any replica serves any result from the shared folder.
  for (int i = 0; i < kReplicas; ++i)
    EXPECT_EQ(FetchSha(*clients_[i], ids[i * 7], "fetched-" + std::to_string(i) + ".vdb"),
              *shas.begin());

  // Each job's end was recorded exactly once, by exactly one replica, and
  // the work was shared.
  std::vector<std::string> logs;
  for (int i = 0; i < kReplicas; ++i) {
    replicas_[i]->Stop();
    logs.push_back(ReadText(LogPath(i)));
  }
  int replicas_that_worked = 0;
  for (const std::string& log : logs) replicas_that_worked += CountOf(log, "event=end") > 0;
  EXPECT_GE(replicas_that_worked, 2);
  for (const std::string& id : ids) {
    size_t ends = 0, starts = 0;
    for (const std::string& log : logs) {
      ends += CountOf(log, "job=" + id + " event=end");
      starts += CountOf(log, "job=" + id + " event=start");
    }
    EXPECT_EQ(ends, 1u) << id;
    EXPECT_EQ(starts, 1u) << id;
  }
  // Log lines carry the replica id.
  EXPECT_NE(logs[0].find("replica=replica0"), std::string::npos);
}

TEST_F(ReplicasE2E, KilledReplicasJobIsFinishedByAnotherWithIdenticalBytes) {
  const v1::JobSpec spec = Tetrahedron(32, 2'000'000'000);
  // The undisturbed run, for the reference bytes.
  auto reference = clients_[0]->Submit(spec);
  ASSERT_TRUE(reference.ok()) << reference.status();
  const v1::Job ref_done = AwaitEnd(reference->id(), *clients_[0]);
  ASSERT_EQ(ref_done.state(), v1::JOB_STATE_SUCCEEDED) << ref_done.error();
  EXPECT_EQ(ref_done.attempts(), 1u);

  auto job = clients_[1]->Submit(spec);
  ASSERT_TRUE(job.ok()) << job.status();
  const int victim = AwaitRunningWithProgress(job->id(), *clients_[1]);
  ASSERT_GE(victim, 0);
  replicas_[victim]->Kill();
  const int survivor = (victim + 1) % kReplicas;

  const v1::Job done = AwaitEnd(job->id(), *clients_[survivor]);
  ASSERT_EQ(done.state(), v1::JOB_STATE_SUCCEEDED) << done.error();
  EXPECT_EQ(done.attempts(), 2u);
  EXPECT_EQ(done.result().sha256(), ref_done.result().sha256());
  EXPECT_EQ(FetchSha(*clients_[survivor], job->id(), "failover.vdb"), ref_done.result().sha256());
  EXPECT_EQ(FetchSha(*clients_[survivor], reference->id(), "reference.vdb"),
            ref_done.result().sha256());
}

// kill -9 of a replica: ListWorkers on the others shows it lost once its
// lease has passed, and the event log of its job says the lease was lost
// and who claimed the job next.
TEST_F(ReplicasE2E, KilledReplicaIsListedLostAndItsJobsLogSaysSo) {
  auto workers = clients_[0]->ListWorkers();
  ASSERT_TRUE(workers.ok()) << workers.status();
  ASSERT_EQ(workers->workers_size(), kReplicas);
  for (const auto& w : workers->workers()) {
    EXPECT_FALSE(w.lost()) << w.replica_id();
    EXPECT_EQ(w.worker_slots(), 2u);
    EXPECT_EQ(w.threads_per_job(), 1u);
  }
  auto job = clients_[0]->Submit(Tetrahedron(32, 2'000'000'000));
  ASSERT_TRUE(job.ok()) << job.status();
  const int victim = AwaitRunningWithProgress(job->id(), *clients_[0]);
  ASSERT_GE(victim, 0);
  const std::string victim_worker = clients_[0]->Get(job->id())->worker();
  replicas_[victim]->Kill();
  const int survivor = (victim + 1) % kReplicas;
  const v1::Job done = AwaitEnd(job->id(), *clients_[survivor]);
  ASSERT_EQ(done.state(), v1::JOB_STATE_SUCCEEDED) << done.error();

  // The lease (1.5 s) has passed since the victim's last heartbeat: the
  // job was claimed again only after it.
  workers = clients_[survivor]->ListWorkers();
  ASSERT_TRUE(workers.ok()) << workers.status();
  ASSERT_EQ(workers->workers_size(), kReplicas);
  for (const auto& w : workers->workers())
    EXPECT_EQ(w.lost(), w.replica_id() == ReplicaId(victim)) << w.replica_id();

  auto events = clients_[survivor]->GetJobEvents(job->id(), 0, 500);
  ASSERT_TRUE(events.ok()) << events.status();
  std::vector<std::string> claims;
  for (const auto& e : events->events())
    if (e.kind() == "claimed" || e.kind() == "lease_lost")
      claims.push_back(e.kind() + " " + e.fields().at("worker") + " " + e.fields().at("attempt"));
  ASSERT_EQ(claims.size(), 3u) << absl::StrJoin(claims, "; ");
  EXPECT_EQ(claims[0], "claimed " + victim_worker + " 1");
  EXPECT_EQ(claims[1], "lease_lost " + victim_worker + " 1");
  EXPECT_EQ(claims[2].rfind("claimed ", 0), 0u);
  EXPECT_EQ(claims[2].find(ReplicaId(victim) + "/"), std::string::npos) << claims[2];
  EXPECT_EQ(events->events(events->events_size() - 1).kind(), "succeeded");
}

TEST_F(ReplicasE2E, AShardedJobOverThreeReplicasEqualsTheUnshardedResult) {
  v1::JobSpec spec = Tetrahedron(32, 60'000'000);
  spec.mutable_chaos_game()->mutable_color()->set_mode(v1::COLOR_MODE_ADDRESS);
  auto whole = clients_[0]->Submit(spec);
  ASSERT_TRUE(whole.ok()) << whole.status();
  const v1::Job whole_done = AwaitEnd(whole->id(), *clients_[0]);
  ASSERT_EQ(whole_done.state(), v1::JOB_STATE_SUCCEEDED) << whole_done.error();
  const std::string expected = FetchSha(*clients_[0], whole->id(), "whole.vdb");
  EXPECT_EQ(expected, whole_done.result().sha256());
  for (uint32_t shards : {1u, 3u, 8u}) {
    SCOPED_TRACE(shards);
    spec.set_shards(shards);
    NimbusClient& submitter = *clients_[shards % kReplicas];
    auto job = submitter.Submit(spec);
    ASSERT_TRUE(job.ok()) << job.status();
    const v1::Job done = AwaitEnd(job->id(), submitter);
    ASSERT_EQ(done.state(), v1::JOB_STATE_SUCCEEDED) << done.error();
    // Fetched from a replica other than the submitter's.
    EXPECT_EQ(FetchSha(*clients_[(shards + 1) % kReplicas], job->id(),
                       "sharded-" + std::to_string(shards) + ".vdb"),
              expected);
    if (shards < 8) continue;
    // The shards were claimed independently: more than one replica ran some.
    int replicas_with_shards = 0;
    for (int i = 0; i < kReplicas; ++i)
      if (ReadText(LogPath(i)).find(job->id() + ".shard-") != std::string::npos)
        ++replicas_with_shards;
    EXPECT_GE(replicas_with_shards, 2);
  }
}

TEST_F(ReplicasE2E, WatcherOnOneReplicaSeesProgressAndPreviewsOfAJobOnAnother) {
  // Long enough on any machine; the watcher cancels it once it has seen
  // what it came for, so the test takes about as long as that.
  auto job = clients_[0]->Submit(Tetrahedron(32, 2'000'000'000));
  ASSERT_TRUE(job.ok()) << job.status();
  const int runner = AwaitRunningWithProgress(job->id(), *clients_[0]);
  ASSERT_GE(runner, 0);
  const int watcher = (runner + 1) % kReplicas;
  std::set<uint64_t> progress;
  std::vector<v1::JobState> states;
  std::vector<uint64_t> preview_sequences;
  std::thread canceller;
  client::WatchOptions options;
  options.preview_resolution = 16;
  options.preview_interval_seconds = 0.1;
  auto end = clients_[watcher]->Watch(job->id(), options, [&](const v1::WatchJobResponse& r) {
    progress.insert(r.job().progress().done());
    states.push_back(r.job().state());
    if (r.has_preview()) {
      preview_sequences.push_back(r.preview().sequence());
      EXPECT_FALSE(r.preview().vdb().empty());
      EXPECT_EQ(r.preview().resolution(0), 16);
    }
    if (!canceller.joinable() && progress.size() >= 3 && preview_sequences.size() >= 2)
      canceller = std::thread([&] { (void)clients_[runner]->Cancel(job->id()); });
  });
  if (canceller.joinable()) canceller.join();
  ASSERT_TRUE(end.ok()) << end.status();
  // Progress arrived while it ran elsewhere (heartbeats), and previews made
  // on the running replica reached the watcher's, in sequence order; then
  // the end (the watcher's cancel).
  EXPECT_GE(progress.size(), 3u);
  EXPECT_GE(preview_sequences.size(), 2u);
  EXPECT_TRUE(std::is_sorted(preview_sequences.begin(), preview_sequences.end()));
  ASSERT_FALSE(states.empty());
  EXPECT_EQ(states.front(), v1::JOB_STATE_RUNNING);
  EXPECT_EQ(end->state(), v1::JOB_STATE_CANCELLED);
  EXPECT_EQ(states.back(), v1::JOB_STATE_CANCELLED);
}

// A watcher asking for events on one replica receives the log of a job
// another replica runs as it grows: the claim while the job runs, and in
// all exactly what GetJobEvents reads afterwards, once each and in order
// (the end event is written with the job's end, so it comes by the last
// message). A watch started after seq 2 begins at 3.
TEST_F(ReplicasE2E, WatcherWithEventsReceivesTheJobsLogAsItGrows) {
  // Runs some seconds: long enough to be watched while it runs.
  auto job = clients_[0]->Submit(Tetrahedron(32, 1'000'000'000));
  ASSERT_TRUE(job.ok()) << job.status();
  const int runner = AwaitRunningWithProgress(job->id(), *clients_[0]);
  ASSERT_GE(runner, 0);
  const int watcher = (runner + 1) % kReplicas;
  std::vector<std::string> streamed;  // "seq kind"
  std::vector<std::string> while_running;
  client::WatchOptions options;
  options.events = true;
  auto end = clients_[watcher]->Watch(job->id(), options, [&](const v1::WatchJobResponse& r) {
    for (const v1::JobEvent& e : r.events()) {
      streamed.push_back(std::to_string(e.seq()) + " " + e.kind());
      if (r.job().state() == v1::JOB_STATE_RUNNING) while_running.push_back(e.kind());
    }
  });
  ASSERT_TRUE(end.ok()) << end.status();
  ASSERT_EQ(end->state(), v1::JOB_STATE_SUCCEEDED) << end->error();

  auto log = clients_[runner]->GetJobEvents(job->id(), 0, 500);
  ASSERT_TRUE(log.ok()) << log.status();
  std::vector<std::string> read;
  for (const v1::JobEvent& e : log->events())
    read.push_back(std::to_string(e.seq()) + " " + e.kind());
  EXPECT_EQ(streamed, read);
  // seq 1, 2, ... n: the submission (logged with the job), the claim, its
  // phases, the end.
  ASSERT_GE(read.size(), 3u);
  for (size_t i = 0; i < read.size(); ++i)
    EXPECT_EQ(read[i].substr(0, read[i].find(' ')), std::to_string(i + 1)) << read[i];
  EXPECT_EQ(read[0], "1 submitted");
  EXPECT_EQ(read[1], "2 claimed");
  EXPECT_EQ(read.back(), std::to_string(read.size()) + " succeeded");
  EXPECT_NE(std::find(while_running.begin(), while_running.end(), "claimed"), while_running.end());

  // The resumed form: after seq 2, one message (the job has ended) with the rest.
  auto stub = v1::NimbusService::NewStub(
      grpc::CreateChannel(replicas_[watcher]->target(), grpc::InsecureChannelCredentials()));
  grpc::ClientContext ctx;
  v1::WatchJobRequest req;
  req.set_job_id(job->id());
  req.set_include_events(true);
  req.set_events_after_seq(2);
  auto reader = stub->WatchJob(&ctx, req);
  std::vector<std::string> resumed;
  v1::WatchJobResponse msg;
  while (reader->Read(&msg))
    for (const v1::JobEvent& e : msg.events())
      resumed.push_back(std::to_string(e.seq()) + " " + e.kind());
  ASSERT_TRUE(reader->Finish().ok());
  EXPECT_EQ(resumed, std::vector<std::string>(read.begin() + 2, read.end()));
}

TEST_F(ReplicasE2E, CancelOnAnotherReplicaStopsTheJobAndAnswersItsEnd) {
  auto job = clients_[0]->Submit(Tetrahedron(32, 2'000'000'000));
  ASSERT_TRUE(job.ok()) << job.status();
  const int runner = AwaitRunningWithProgress(job->id(), *clients_[0]);
  ASSERT_GE(runner, 0);
  // CancelJob waits (up to 5 s) for the job to stop on the other replica:
  // its worker sees the cancel at its next heartbeat (250 ms here).
  auto cancelled = clients_[(runner + 1) % kReplicas]->Cancel(job->id());
  ASSERT_TRUE(cancelled.ok()) << cancelled.status();
  EXPECT_EQ(cancelled->state(), v1::JOB_STATE_CANCELLED);
  EXPECT_EQ(cancelled->status().code(), 1);  // google.rpc.Code CANCELLED
  EXPECT_EQ(AwaitEnd(job->id(), *clients_[runner]).state(), v1::JOB_STATE_CANCELLED);
}

}  // namespace
}  // namespace nimbus
