// End to end against a real nimbusd on loopback: submit, watch previews,
// fetch, kill -9 and restart, cancel, error codes, and reads that a blocked
// job store must not hold up.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <sqlite3.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <csignal>
#include <fstream>
#include <future>
#include <optional>
#include <sstream>
#include <thread>

#include "client/nimbus_client.h"
#include "core/base/sha256.h"
#include "core/io/vdb_io.h"
#include "proto/spec_convert.h"
#include "proto/spec_io.h"
#include "server/data_dir_lock.h"
#include "tests/support/decoded_content.h"
#include "tests/support/nimbusd_process.h"
#include "tests/support/server_fixture.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

using client::NimbusClient;

constexpr int kCancelledCode = 1;  // google.rpc.Code CANCELLED

v1::JobSpec Tetrahedron(int resolution, uint64_t iterations) {
  auto spec = spec::LoadSpecFile(testing::SourcePath("examples/sierpinski_tetrahedron.json"));
  EXPECT_TRUE(spec.ok());
  spec->mutable_grid()->set_resolution(0, resolution);
  spec->mutable_chaos_game()->set_iterations(iterations);
  return *spec;
}

// Runs until cancelled: far more points than any test waits for.
v1::JobSpec Endless() { return Tetrahedron(64, uint64_t{1} << 38); }

bool RunningWithProgress(const v1::Job& job) {
  return job.state() == v1::JOB_STATE_RUNNING && job.progress().done() > 0;
}

class ServiceE2E : public ::testing::Test {
 protected:
  void SetUp() override { Restart({}); }

  // (Re)starts nimbusd with the common arguments plus `more`; `port` 0
  // picks a new port.
  void Restart(std::vector<std::string> more, int port = 0) {
    server_.Kill();
    std::vector<std::string> args = {"--workers", "1", "--threads-per-job", "2",
                                     "--log-level", "warn"};
    args.insert(args.end(), more.begin(), more.end());
    server_.set_args(args);
    absl::Status s = server_.Start(port);
    ASSERT_TRUE(s.ok()) << s;
    client_ = NimbusClient::Connect(server_.target());
    ASSERT_TRUE(client_->WaitForReady(20).ok()) << "nimbusd did not answer";
  }
  NimbusClient& client() { return *client_; }
  // A second connection, for calls made while `client()` is mid-watch.
  std::unique_ptr<NimbusClient> Other() { return NimbusClient::Connect(server_.target()); }
  // Polls until job `id` is RUNNING; false if it ends or a minute passes.
  bool AwaitRunning(const std::string& id) {
    for (int i = 0; i < 3000; ++i) {
      auto job = client().Get(id);
      if (!job.ok()) return false;
      if (job->state() == v1::JOB_STATE_RUNNING) return true;
      if (job->state() != v1::JOB_STATE_QUEUED) return false;
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    return false;
  }

  testing::TempDir dir_;
  testing::NimbusdProcess server_{dir_ / "data"};
  std::unique_ptr<NimbusClient> client_;
};

TEST_F(ServiceE2E, WatchSendsNewestPreviewsOnly) {
  auto job = client().Submit(Endless());
  ASSERT_TRUE(job.ok()) << job.status();
  EXPECT_EQ(job->state(), v1::JOB_STATE_QUEUED);

  client::WatchOptions o;
  o.preview_resolution = 16;
  o.preview_interval_seconds = 0.05;
  int previews = 0;
  uint64_t last_seq = 0;
  bool saw_running = false;
  auto other = Other();
  // Three previews are the event we wait for; then the job is cancelled.
  auto final_job = client().Watch(job->id(), o, [&](const v1::WatchJobResponse& r) {
    saw_running |= r.job().state() == v1::JOB_STATE_RUNNING;
    if (!r.has_preview()) return;
    EXPECT_GT(r.preview().sequence(), last_seq);  // newest only, never repeated
    last_seq = r.preview().sequence();
    auto vol = ReadVdbBytes(r.preview().vdb());
    ASSERT_TRUE(vol.ok()) << vol.status();
    EXPECT_EQ(vol->frame.resolution, (Int3{16, 16, 16}));
    if (++previews == 3) {
      ASSERT_TRUE(other->Cancel(job->id()).ok());
    }
  });
  ASSERT_TRUE(final_job.ok()) << final_job.status();
  EXPECT_EQ(final_job->state(), v1::JOB_STATE_CANCELLED);
  EXPECT_TRUE(saw_running);
  EXPECT_GE(previews, 3);
}

TEST_F(ServiceE2E, SubmitWatchAndFetch) {
  const v1::JobSpec spec = Tetrahedron(64, 600'000'000);
  auto job = client().Submit(spec);
  ASSERT_TRUE(job.ok()) << job.status();
  auto final_job = client().Watch(job->id(), {}, [](const v1::WatchJobResponse&) {});
  ASSERT_TRUE(final_job.ok()) << final_job.status();
  EXPECT_EQ(final_job->state(), v1::JOB_STATE_SUCCEEDED) << final_job->error();
  EXPECT_EQ(final_job->status().code(), 0);
  EXPECT_FALSE(final_job->cancel_requested());

  const auto out = dir_ / "tet.vdb";
  ASSERT_TRUE(client().Fetch(job->id(), out).ok());
  EXPECT_EQ(*Sha256File(out), final_job->result().sha256());
  auto vol = ReadVdbFile(out);
  ASSERT_TRUE(vol.ok()) << vol.status();
  EXPECT_EQ(vol->frame.resolution, (Int3{64, 64, 64}));
  EXPECT_EQ(std::get<std::string>(*vol->Find("nimbus_spec_hash")), spec::SpecHash(spec));
  EXPECT_EQ(std::get<int64_t>(*vol->Find("nimbus_iterations")), 600'000'000);
  EXPECT_EQ(std::get<int64_t>(*vol->Find("nimbus_seed")), 1);
  float max = 0;
  for (float v : vol->values) max = std::max(max, v);
  EXPECT_FLOAT_EQ(max, 1.0f);

  // Resume: keep half the file as a partial download and fetch again.
  const auto resumed = dir_ / "resumed.vdb";
  {
    std::ifstream in(out, std::ios::binary);
    std::string bytes((std::istreambuf_iterator<char>(in)), {});
    std::ofstream(resumed.string() + ".part", std::ios::binary)
        << bytes.substr(0, bytes.size() / 2);
  }
  ASSERT_TRUE(client().Fetch(job->id(), resumed).ok());
  EXPECT_EQ(*Sha256File(resumed), final_job->result().sha256());
  // A corrupt partial download is detected and discarded.
  std::ofstream(dir_.path().string() + "/bad.vdb.part", std::ios::binary) << "garbage!";
  EXPECT_EQ(client().Fetch(job->id(), dir_ / "bad.vdb").code(), absl::StatusCode::kDataLoss);
}

// A download of many chunks (the server sends 1 MiB at a time and the
// client queues up to eight for its hashing thread): every byte arrives in
// order, a resume from a partial file past the queue's depth gives the
// same file, and a partial file corrupted near its end is caught.
TEST_F(ServiceE2E, ManyChunkDownloadsHashEveryByteInOrder) {
  v1::JobSpec spec = testing::LoadExample("cumulus.json");
  spec.mutable_fractal_field()->clear_shape();  // every voxel active: a dense file
  spec.mutable_grid()->clear_resolution();
  spec.mutable_grid()->add_resolution(224);
  auto job = client().Submit(spec);
  ASSERT_TRUE(job.ok()) << job.status();
  auto done = client().Watch(job->id(), {}, [](const v1::WatchJobResponse&) {});
  ASSERT_TRUE(done.ok()) << done.status();
  ASSERT_EQ(done->state(), v1::JOB_STATE_SUCCEEDED) << done->error();
  ASSERT_GT(done->result().size_bytes(), 12u << 20) << "too small to fill the queue";

  const auto out = dir_ / "cloud.vdb";
  ASSERT_TRUE(client().Fetch(job->id(), out).ok());
  EXPECT_EQ(*Sha256File(out), done->result().sha256());
  std::string bytes;
  {
    std::ifstream in(out, std::ios::binary);
    bytes.assign(std::istreambuf_iterator<char>(in), {});
  }
  ASSERT_EQ(bytes.size(), done->result().size_bytes());

  const auto resumed = dir_ / "resumed.vdb";
  std::ofstream(resumed.string() + ".part", std::ios::binary) << bytes.substr(0, 9u << 20);
  ASSERT_TRUE(client().Fetch(job->id(), resumed).ok());
  EXPECT_EQ(*Sha256File(resumed), done->result().sha256());

  std::string corrupt = bytes.substr(0, bytes.size() - 1000);
  corrupt[corrupt.size() - 3] ^= 1;
  const auto bad = dir_ / "bad.vdb";
  std::ofstream(bad.string() + ".part", std::ios::binary) << corrupt;
  EXPECT_EQ(client().Fetch(job->id(), bad).code(), absl::StatusCode::kDataLoss);
  EXPECT_FALSE(std::filesystem::exists(bad));
  EXPECT_FALSE(std::filesystem::exists(bad.string() + ".part"));
}

// The lease outlives the test, so only start-up recovery can run the job
// again; the watch rides out the restart on the same address, and the
// events it asked for arrive once each across the reconnect.
TEST_F(ServiceE2E, RestartRecoversTheRunningJobAndTheWatchResumes) {
  Restart({"--lease-ms", "600000"});
  auto job = client().Submit(Tetrahedron(64, 800'000'000));
  ASSERT_TRUE(job.ok());
  bool restarted = false;
  auto watcher = Other();
  client::WatchOptions options;
  options.events = true;
  std::vector<std::string> streamed;  // "seq kind"
  auto final_job = watcher->Watch(job->id(), options, [&](const v1::WatchJobResponse& r) {
    for (const v1::JobEvent& e : r.events())
      streamed.push_back(std::to_string(e.seq()) + " " + e.kind());
    if (restarted || !RunningWithProgress(r.job())) return;
    restarted = true;
    EXPECT_EQ(r.job().attempts(), 1u);
    // kill -9 while the stream is open, and come back on the same port.
    Restart({"--lease-ms", "600000"}, server_.port());
  });
  ASSERT_TRUE(final_job.ok()) << final_job.status();
  EXPECT_TRUE(restarted);
  EXPECT_EQ(final_job->state(), v1::JOB_STATE_SUCCEEDED) << final_job->error();
  EXPECT_EQ(final_job->attempts(), 2u);
  ASSERT_TRUE(client().Fetch(job->id(), dir_ / "after_restart.vdb").ok());
  auto log = client().GetJobEvents(job->id(), 0, 500);
  ASSERT_TRUE(log.ok()) << log.status();
  std::vector<std::string> read;
  for (const v1::JobEvent& e : log->events())
    read.push_back(std::to_string(e.seq()) + " " + e.kind());
  EXPECT_EQ(streamed, read);
  EXPECT_NE(std::find(read.begin(), read.end(), "1 submitted"), read.end());
  EXPECT_EQ(std::count_if(read.begin(), read.end(),
                          [](const std::string& e) { return e.ends_with(" claimed"); }),
            2);
}

// `nimbus watch --events` prints each event of the job's log as `nimbus
// events` does, in order, beside its progress lines (stderr).
TEST_F(ServiceE2E, CliWatchWithEventsPrintsTheLogAsEventsDoes) {
  auto job = client().Submit(Tetrahedron(32, 50'000'000));
  ASSERT_TRUE(job.ok()) << job.status();
  const std::string cli =
      std::string(NIMBUS_BIN_DIR) + "/nimbus --server " + server_.target() + " ";
  const std::string watch =
      cli + "watch " + job->id() + " --events 2>" + (dir_ / "watch.txt").string() + " >/dev/null";
  ASSERT_EQ(WEXITSTATUS(std::system(watch.c_str())), 0)
      << testing::ReadFileBytes(dir_ / "watch.txt");
  const std::string events = cli + "events " + job->id() + " >" + (dir_ / "events.txt").string();
  ASSERT_EQ(WEXITSTATUS(std::system(events.c_str())), 0);
  const std::string printed = testing::ReadFileBytes(dir_ / "watch.txt");
  std::istringstream log(testing::ReadFileBytes(dir_ / "events.txt"));
  size_t at = 0;
  int lines = 0;
  for (std::string line; std::getline(log, line); ++lines) {
    at = printed.find(line + "\n", at);
    ASSERT_NE(at, std::string::npos) << "missing or out of order: " << line << "\n" << printed;
  }
  EXPECT_GE(lines, 3);  // submitted, claimed, ..., succeeded
}

TEST_F(ServiceE2E, CancelAnswersWithTheStoppedJob) {
  auto job = client().Submit(Endless());
  ASSERT_TRUE(job.ok());
  auto other = Other();
  std::optional<absl::StatusOr<v1::Job>> cancelled;
  auto final_job = client().Watch(job->id(), {}, [&](const v1::WatchJobResponse& r) {
    if (cancelled || !RunningWithProgress(r.job())) return;
    // The result of an unfinished job is not there yet.
    EXPECT_EQ(other->Fetch(job->id(), dir_ / "x.vdb").code(),
              absl::StatusCode::kFailedPrecondition);
    cancelled = other->Cancel(job->id());
  });
  ASSERT_TRUE(cancelled.has_value());
  ASSERT_TRUE(cancelled->ok()) << cancelled->status();
  // CancelJob waited for the worker to stop the job.
  const v1::Job& answer = **cancelled;
  EXPECT_EQ(answer.state(), v1::JOB_STATE_CANCELLED);
  EXPECT_EQ(answer.status().code(), kCancelledCode);
  EXPECT_EQ(answer.status().message(), answer.error());
  EXPECT_FALSE(answer.cancel_requested());
  ASSERT_TRUE(final_job.ok()) << final_job.status();
  EXPECT_EQ(final_job->state(), v1::JOB_STATE_CANCELLED);
  // Watching and getting a finished job give its final state at once.
  auto watched = client().Watch(job->id(), {}, [](const v1::WatchJobResponse&) {});
  ASSERT_TRUE(watched.ok());
  EXPECT_EQ(watched->state(), v1::JOB_STATE_CANCELLED);
  auto got = client().Get(job->id());
  ASSERT_TRUE(got.ok());
  EXPECT_EQ(got->status().code(), kCancelledCode);
}

TEST_F(ServiceE2E, CancelNotFinishedInTimeSaysItIsCancelling) {
  Restart({"--cancel-wait-ms", "0"});  // never wait: the job cannot stop in time
  auto other = Other();
  // The interrupt reaches this process's worker at once, so now and then
  // the job has already stopped when the answer is made (then it answers
  // with the end); a few attempts see the answer for a job still running.
  bool saw_running = false;
  for (int attempt = 0; attempt < 5 && !saw_running; ++attempt) {
    auto job = client().Submit(Endless());
    ASSERT_TRUE(job.ok());
    std::optional<absl::StatusOr<v1::Job>> cancelled;
    auto final_job = client().Watch(job->id(), {}, [&](const v1::WatchJobResponse& r) {
      if (!cancelled && RunningWithProgress(r.job())) cancelled = other->Cancel(job->id());
    });
    ASSERT_TRUE(cancelled.has_value());
    ASSERT_TRUE(cancelled->ok()) << cancelled->status();
    if ((*cancelled)->state() == v1::JOB_STATE_RUNNING) {
      saw_running = true;
      EXPECT_TRUE((*cancelled)->cancel_requested());
      EXPECT_EQ((*cancelled)->status().code(), 0);
    } else {
      EXPECT_EQ((*cancelled)->state(), v1::JOB_STATE_CANCELLED);
    }
    // Either way it stops, with the code of a cancelled job.
    ASSERT_TRUE(final_job.ok()) << final_job.status();
    EXPECT_EQ(final_job->state(), v1::JOB_STATE_CANCELLED);
    EXPECT_EQ(final_job->status().code(), kCancelledCode);
    EXPECT_FALSE(final_job->cancel_requested());
  }
  EXPECT_TRUE(saw_running) << "every attempt's job had stopped before the answer";
}

TEST_F(ServiceE2E, QueuedJobCancelledAtOnceHasCodeCancelled) {
  // One worker: the endless job, seen running, keeps the second one queued
  // whatever order the claim would take them in.
  auto busy = client().Submit(Endless());
  ASSERT_TRUE(busy.ok()) << busy.status();
  ASSERT_TRUE(AwaitRunning(busy->id()));
  auto queued = client().Submit(Tetrahedron(16, 1000));
  ASSERT_TRUE(queued.ok()) << queued.status();
  auto cancelled = client().Cancel(queued->id());
  ASSERT_TRUE(cancelled.ok()) << cancelled.status();
  EXPECT_EQ(cancelled->state(), v1::JOB_STATE_CANCELLED);
  EXPECT_EQ(cancelled->status().code(), kCancelledCode);
  EXPECT_EQ(cancelled->status().message(), "cancelled by request");
  auto got = client().Get(queued->id());
  ASSERT_TRUE(got.ok());
  EXPECT_EQ(got->state(), v1::JOB_STATE_CANCELLED);
  EXPECT_EQ(got->status().code(), kCancelledCode);
  EXPECT_FALSE(got->cancel_requested());
  // No worker ever held it, so the service logs its end.
  auto log = client().GetJobEvents(queued->id(), 0, 100);
  ASSERT_TRUE(log.ok()) << log.status();
  std::vector<std::string> kinds;
  for (const v1::JobEvent& e : log->events()) kinds.push_back(e.kind());
  EXPECT_EQ(kinds, (std::vector<std::string>{"submitted", "cancel_requested", "cancelled"}));
}

// Another process holds the job database's write lock, the way a slow
// writer would: a cancel (a write) waits for it, but GetJob (a read) of
// another job answers at once, and sees the cancel once it went through.
TEST_F(ServiceE2E, BlockedJobStoreDoesNotHoldUpReads) {
  auto busy = client().Submit(Endless());
  auto a = client().Submit(Tetrahedron(16, 1000));
  auto b = client().Submit(Tetrahedron(16, 1000));
  ASSERT_TRUE(busy.ok() && a.ok() && b.ok());

  sqlite3* db = nullptr;
  ASSERT_EQ(sqlite3_open((dir_ / "data" / "jobs.db").c_str(), &db), SQLITE_OK);
  sqlite3_busy_timeout(db, 10000);
  ASSERT_EQ(sqlite3_exec(db, "BEGIN IMMEDIATE", nullptr, nullptr, nullptr), SQLITE_OK);
  auto other = Other();
  std::future<absl::StatusOr<v1::Job>> cancel =
      std::async(std::launch::async, [&] { return other->Cancel(a->id()); });
  // The cancel cannot finish while the lock is held; this also gives it
  // time to reach the store and wait there.
  EXPECT_EQ(cancel.wait_for(std::chrono::milliseconds(300)), std::future_status::timeout);
  // The lock is held until every read has answered: a read that queued
  // behind the blocked write could only answer once that write had failed
  // (its busy timeout), and the cancel checked below would have failed.
  for (int i = 0; i < 10; ++i) {
    auto got = client().Get(b->id());
    ASSERT_TRUE(got.ok()) << got.status();
    EXPECT_EQ(got->state(), v1::JOB_STATE_QUEUED);
  }
  EXPECT_EQ(cancel.wait_for(std::chrono::seconds(0)), std::future_status::timeout)
      << "the cancel ended while the lock was held";
  ASSERT_EQ(sqlite3_exec(db, "ROLLBACK", nullptr, nullptr, nullptr), SQLITE_OK);
  sqlite3_close(db);

  auto cancelled = cancel.get();
  ASSERT_TRUE(cancelled.ok()) << cancelled.status();
  EXPECT_EQ(cancelled->state(), v1::JOB_STATE_CANCELLED);
  auto got = client().Get(a->id());
  ASSERT_TRUE(got.ok());
  EXPECT_EQ(got->state(), v1::JOB_STATE_CANCELLED);
}

TEST_F(ServiceE2E, GracefulStopExitsCleanly) { EXPECT_EQ(server_.Stop(), 0); }

TEST_F(ServiceE2E, ErrorCodes) {
  EXPECT_EQ(client().Get("j-nope").status().code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(client().Cancel("j-nope").status().code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(client().Fetch("j-nope", dir_ / "n.vdb").code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(client().Watch("j-nope", {}, [](const v1::WatchJobResponse&) {}).status().code(),
            absl::StatusCode::kNotFound);

  v1::JobSpec bad = Tetrahedron(64, 10);
  bad.mutable_grid()->set_resolution(0, 0);
  auto s = client().Submit(bad).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("grid.resolution[0]"), std::string::npos) << s;

  v1::JobSpec huge = Tetrahedron(4000, 10);
  s = client().Submit(huge).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kResourceExhausted) << s;

  // Idempotent submit.
  auto a = client().Submit(Tetrahedron(16, 1000), "req-1");
  auto b = client().Submit(Tetrahedron(16, 1000), "req-1");
  ASSERT_TRUE(a.ok() && b.ok());
  EXPECT_EQ(a->id(), b->id());
  v1::ListJobsRequest req;
  auto list = client().List(req);
  ASSERT_TRUE(list.ok());
  EXPECT_EQ(list->jobs_size(), 1);
}

// The CLI end to end: the main job through an embedded server, and bad input.
int RunCli(const std::string& args) {
  const std::string cmd = std::string(NIMBUS_BIN_DIR) + "/nimbus " + args + " >/dev/null 2>&1";
  const int rc = std::system(cmd.c_str());
  return WEXITSTATUS(rc);
}

TEST(CliE2E, RenderWithEmbeddedServerAndBadInput) {
  testing::TempDir dir;
  const std::string spec = testing::SourcePath("examples/sierpinski_tetrahedron.txtpb").string();
  const std::string data = "--data-dir " + (dir / "data").string();
  EXPECT_EQ(RunCli(data + " render " + spec + " -o " + (dir / "t.vdb").string() + " --previews " +
                   (dir / "previews").string()),
            0);
  EXPECT_TRUE(ReadVdbFile(dir / "t.vdb").ok());
  EXPECT_EQ(RunCli("validate " + spec), 0);
  std::ofstream(dir / "bad.json") << "{\"grid\": {\"resolution\": [0]}}";
  EXPECT_EQ(RunCli("validate " + (dir / "bad.json").string()), 2);
  std::ofstream(dir / "broken.json") << "{\"grid\": ";
  EXPECT_EQ(RunCli(data + " render " + (dir / "broken.json").string() + " -o x.vdb"), 2);
  EXPECT_EQ(RunCli(data + " get j-missing"), 2);
}

TEST(CliE2E, DeeplyNestedTextSpecIsAnErrorNotACrash) {
  testing::TempDir dir;
  std::string open, close;
  for (int i = 0; i < 5000; ++i) open += "random_balls { inside { ", close += "} } ";
  std::ofstream(dir / "deep.txtpb") << "set_ifs { maps { condensation { " << open
                                    << "sphere { radius: 1 } " << close << "} } }";
  const std::string spec = (dir / "deep.txtpb").string();
  EXPECT_EQ(RunCli("validate " + spec), 2);
  EXPECT_EQ(RunCli("--data-dir " + (dir / "data").string() + " submit " + spec), 2);
}

// A render started while another process serves the default data dir (a
// second terminal) runs in a private data dir and removes it; commands that
// need the shared queue are refused with a message naming the holder.
TEST(CliE2E, RenderWhileAnotherProcessServesTheDataDir) {
  testing::TempDir dir;
  std::filesystem::create_directories(dir / "data");
  std::filesystem::create_directories(dir / "tmp");
  auto held = server::DataDirLock::Acquire(dir / "data");
  ASSERT_TRUE(held.ok()) << held.status();
  const std::string env = "NIMBUS_DATA_DIR=" + (dir / "data").string() +
                          " TMPDIR=" + (dir / "tmp").string() + " ";
  const std::string spec = testing::SourcePath("examples/sierpinski_tetrahedron.json").string();
  const std::string log = (dir / "render.log").string();
  const std::string render = env + NIMBUS_BIN_DIR + "/nimbus --threads 1 render --no-cache " +
                             spec + " -o " + (dir / "t.vdb").string() + " 2>" + log;
  ASSERT_EQ(WEXITSTATUS(std::system(render.c_str())), 0);
  // What the file means (voxels, topology, metadata read back through
  // OpenVDB), whatever writer wrote its bytes.
  auto digest = testing::VdbContentDigest(dir / "t.vdb");
  ASSERT_TRUE(digest.ok()) << digest.status();
  EXPECT_EQ(digest->substr(0, 16), "e7e0f0387f46d3e4");
  std::stringstream text;
  text << std::ifstream(log).rdbuf();
  EXPECT_NE(text.str().find("uses a private data dir"), std::string::npos) << text.str();
  EXPECT_TRUE(std::filesystem::is_empty(dir / "tmp"));  // the private dir is gone
  const std::string jobs = env + NIMBUS_BIN_DIR + "/nimbus jobs 2>" + log;
  EXPECT_NE(WEXITSTATUS(std::system(jobs.c_str())), 0);
  text.str("");
  text << std::ifstream(log).rdbuf();
  EXPECT_NE(text.str().find("(pid " + std::to_string(::getpid()) + ")"), std::string::npos)
      << text.str();
}

// Ctrl-C during `nimbus render` cancels the job instead of leaving it
// queued: the command ends with the job's failure code, writes no result,
// and the job is CANCELLED in the data dir afterwards.
TEST(CliE2E, CtrlCCancelsTheRendersJob) {
  testing::TempDir dir;
  const std::string data = (dir / "data").string(), log = (dir / "render.log").string();
  // The README's example, run for far longer than the test.
  std::string spec =
      testing::ReadFileBytes(testing::SourcePath("examples/sierpinski_tetrahedron.json"));
  const size_t it = spec.find("\"iterations\"");
  ASSERT_NE(it, std::string::npos);
  spec.replace(it, spec.find(',', it) - it, "\"iterations\": \"1000000000000\"");
  std::ofstream(dir / "long.json") << spec;
  // Everything the child needs is built before fork: it may only exec.
  const std::string bin = std::string(NIMBUS_BIN_DIR) + "/nimbus";
  const std::string spec_path = (dir / "long.json").string(), out = (dir / "long.vdb").string();
  const int log_fd = ::open(log.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  ASSERT_GE(log_fd, 0);
  const pid_t pid = ::fork();
  ASSERT_GE(pid, 0);
  if (pid == 0) {
    ::dup2(log_fd, STDERR_FILENO);
    ::execl(bin.c_str(), bin.c_str(), "--data-dir", data.c_str(), "--threads", "1", "render",
            "--no-cache", spec_path.c_str(), "-o", out.c_str(), static_cast<char*>(nullptr));
    ::_exit(127);
  }
  ::close(log_fd);
  // Interrupt once the job is queued (its id is in the log).
  std::string job;
  for (int i = 0; i < 600 && job.empty(); ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
    const std::string text = testing::ReadFileBytes(log);
    if (const size_t at = text.find("job j-");
        at != std::string::npos && text.find(" queued", at) != std::string::npos)
      job = text.substr(at + 4, text.find(' ', at + 4) - at - 4);
  }
  ASSERT_FALSE(job.empty()) << testing::ReadFileBytes(log);
  ASSERT_EQ(::kill(pid, SIGINT), 0);
  // A render that ignored the signal would run for hours: give up after a minute.
  int status = 0;
  pid_t done = 0;
  for (int i = 0; i < 1200 && done == 0; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
    done = ::waitpid(pid, &status, WNOHANG);
  }
  if (done == 0) {
    ::kill(pid, SIGKILL);
    ::waitpid(pid, &status, 0);
    FAIL() << "the render kept running after Ctrl-C: " << testing::ReadFileBytes(log);
  }
  ASSERT_TRUE(WIFEXITED(status)) << status;
  EXPECT_EQ(WEXITSTATUS(status), 1) << testing::ReadFileBytes(log);
  EXPECT_NE(testing::ReadFileBytes(log).find(job + " cancelled"), std::string::npos)
      << testing::ReadFileBytes(log);
  EXPECT_FALSE(std::filesystem::exists(dir / "long.vdb"));
  const std::string get = std::string(NIMBUS_BIN_DIR) + "/nimbus --data-dir " + data + " get " +
                          job + " >" + (dir / "job.json").string() + " 2>/dev/null";
  ASSERT_EQ(WEXITSTATUS(std::system(get.c_str())), 0);
  EXPECT_NE(testing::ReadFileBytes(dir / "job.json").find("JOB_STATE_CANCELLED"), std::string::npos)
      << testing::ReadFileBytes(dir / "job.json");
}

// `nimbus render` stops its embedded server once the result is written:
// what it leaves in the data dir is whole. The next render of the same spec is answered from the result
// cache with the same bytes, `nimbus jobs` lists both jobs as succeeded,
// and nimbusd serves the data dir afterwards.
TEST(CliE2E, RenderLeavesItsDataDirWholeForTheNextCommand) {
  testing::TempDir dir;
  auto spec = spec::LoadSpecFile(testing::SourcePath("examples/sierpinski_tetrahedron.json"));
  ASSERT_TRUE(spec.ok()) << spec.status();
  spec->mutable_grid()->set_resolution(0, 48);
  spec->mutable_chaos_game()->set_iterations(2000000);
  std::ofstream(dir / "small.json") << spec::SpecToJson(*spec);
  const std::string nimbus =
      std::string(NIMBUS_BIN_DIR) + "/nimbus --data-dir " + (dir / "data").string() + " ";
  auto render = [&](const char* out) {
    const std::string cmd = nimbus + "render " + (dir / "small.json").string() + " -o " +
                            (dir / out).string() + " 2>>" + (dir / "cli.log").string();
    return WEXITSTATUS(std::system(cmd.c_str()));
  };
  ASSERT_EQ(render("first.vdb"), 0) << testing::ReadFileBytes(dir / "cli.log");
  ASSERT_EQ(render("second.vdb"), 0) << testing::ReadFileBytes(dir / "cli.log");
  EXPECT_EQ(testing::ReadFileBytes(dir / "first.vdb"), testing::ReadFileBytes(dir / "second.vdb"));
  const std::string jobs = nimbus + "jobs --state succeeded >" + (dir / "jobs.txt").string();
  ASSERT_EQ(WEXITSTATUS(std::system(jobs.c_str())), 0);
  const std::string listed = testing::ReadFileBytes(dir / "jobs.txt");
  size_t succeeded = 0;
  for (size_t at = listed.find(" succeeded "); at != std::string::npos;
       at = listed.find(" succeeded ", at + 1))
    ++succeeded;
  EXPECT_EQ(succeeded, 2u) << listed;
  // nimbusd opens the same data dir and serves the first job's result.
  const size_t at = listed.rfind("j-");
  ASSERT_NE(at, std::string::npos) << listed;
  const std::string id = listed.substr(at, listed.find(' ', at) - at);
  testing::NimbusdProcess server(dir / "data", {"--workers", "1", "--log-level", "warn"});
  ASSERT_TRUE(server.Start().ok());
  const std::string fetch = std::string(NIMBUS_BIN_DIR) + "/nimbus --server " + server.target() +
                            " fetch " + id + " -o " + (dir / "served.vdb").string() +
                            " 2>>" + (dir / "cli.log").string();
  ASSERT_EQ(WEXITSTATUS(std::system(fetch.c_str())), 0) << testing::ReadFileBytes(dir / "cli.log");
  EXPECT_EQ(testing::ReadFileBytes(dir / "served.vdb"), testing::ReadFileBytes(dir / "first.vdb"));
  EXPECT_EQ(server.Stop(), 0);
}

// Issue 3, item 7: the same spec and seed give a bitwise-identical .vdb
// with 1 or 2 engine threads, through the whole service (fast affine path,
// and nonlinear maps with colour, an address grid and raw counts).
TEST(CliE2E, SameSpecGivesByteIdenticalFilesWhateverTheThreadCount) {
  testing::TempDir dir;
  for (const char* example : {"sierpinski_tetrahedron.json", "flame_cloud.json"}) {
    SCOPED_TRACE(example);
    auto spec = spec::LoadSpecFile(testing::SourcePath(std::string("examples/") + example));
    ASSERT_TRUE(spec.ok()) << spec.status();
    spec->mutable_grid()->clear_resolution();
    spec->mutable_grid()->add_resolution(64);
    spec->mutable_chaos_game()->set_iterations(3'000'000);
    const std::filesystem::path spec_path = dir / example;
    std::ofstream(spec_path) << spec::SpecToJson(*spec);
    std::vector<std::string> digests;
    for (int threads : {1, 2}) {
      const std::filesystem::path out = dir / (std::to_string(threads) + example + ".vdb");
      ASSERT_EQ(RunCli("--threads " + std::to_string(threads) + " --data-dir " +
                       (dir / ("data" + std::to_string(threads))).string() + " render " +
                       spec_path.string() + " -o " + out.string()),
                0);
      auto digest = Sha256File(out);
      ASSERT_TRUE(digest.ok());
      digests.push_back(*digest);
    }
    EXPECT_EQ(digests[0], digests[1]);
  }
}

}  // namespace
}  // namespace nimbus
