// End to end against a real nimbusd on loopback: submit, watch previews,
// fetch, kill -9 and restart, cancel, error codes.
#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <fstream>
#include <thread>

#include "client/nimbus_client.h"
#include "core/base/sha256.h"
#include "core/io/vdb_io.h"
#include "proto/spec_convert.h"
#include "proto/spec_io.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

using client::NimbusClient;
using Clock = std::chrono::steady_clock;

// A nimbusd child process.
class Nimbusd {
 public:
  Nimbusd(std::filesystem::path data_dir, int port) : data_dir_(std::move(data_dir)), port_(port) {}
  ~Nimbusd() { Kill(SIGKILL); }

  void Start() {
    const std::string bin = std::string(NIMBUS_BIN_DIR) + "/nimbusd";
    const std::string listen = "127.0.0.1:" + std::to_string(port_);
    pid_ = ::fork();
    if (pid_ == 0) {
      ::prctl(PR_SET_PDEATHSIG, SIGKILL);  // never outlive a crashed test
      ::execl(bin.c_str(), bin.c_str(), "--listen", listen.c_str(), "--data-dir", data_dir_.c_str(),
              "--workers", "1", "--threads-per-job", "2", "--log-level", "warn",
              static_cast<char*>(nullptr));
      ::_exit(127);
    }
    client_ = NimbusClient::Connect(listen);
    ASSERT_TRUE(client_->WaitForReady(20).ok()) << "nimbusd did not come up";
  }
  void Kill(int sig) {
    if (pid_ <= 0) return;
    ::kill(pid_, sig);
    int status;
    ::waitpid(pid_, &status, 0);
    pid_ = -1;
  }
  NimbusClient& client() { return *client_; }
  std::string target() const { return "127.0.0.1:" + std::to_string(port_); }

 private:
  std::filesystem::path data_dir_;
  int port_;
  pid_t pid_ = -1;
  std::unique_ptr<NimbusClient> client_;
};

v1::JobSpec Tetrahedron(int resolution, uint64_t iterations) {
  auto spec = spec::LoadSpecFile(testing::SourcePath("examples/sierpinski_tetrahedron.json"));
  EXPECT_TRUE(spec.ok());
  spec->mutable_grid()->set_resolution(0, resolution);
  spec->mutable_chaos_game()->set_iterations(iterations);
  return *spec;
}

class ServiceE2E : public ::testing::Test {
 protected:
  void SetUp() override {
    server_ = std::make_unique<Nimbusd>(dir_ / "data", testing::FreePort());
    server_->Start();
  }
  // Waits until the job is running with some progress.
  v1::Job WaitRunning(const std::string& id) {
    const auto deadline = Clock::now() + std::chrono::seconds(30);
    while (Clock::now() < deadline) {
      auto job = server_->client().Get(id);
      if (job.ok() && job->state() == v1::JOB_STATE_RUNNING && job->progress().done() > 0)
        return *job;
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    ADD_FAILURE() << "job " << id << " never ran";
    return {};
  }
  testing::TempDir dir_;
  std::unique_ptr<Nimbusd> server_;
};

TEST_F(ServiceE2E, SubmitWatchPreviewsAndFetch) {
  const v1::JobSpec spec = Tetrahedron(64, 600'000'000);
  auto job = server_->client().Submit(spec);
  ASSERT_TRUE(job.ok()) << job.status();
  EXPECT_EQ(job->state(), v1::JOB_STATE_QUEUED);

  client::WatchOptions o;
  o.preview_resolution = 16;
  o.preview_interval_seconds = 0.2;
  int previews = 0;
  uint64_t last_seq = 0;
  bool saw_running = false;
  auto final_job = server_->client().Watch(job->id(), o, [&](const v1::WatchJobResponse& r) {
    saw_running |= r.job().state() == v1::JOB_STATE_RUNNING;
    if (!r.has_preview()) return;
    EXPECT_GT(r.preview().sequence(), last_seq);  // newest only, never repeated
    last_seq = r.preview().sequence();
    auto vol = ReadVdbBytes(r.preview().vdb());
    ASSERT_TRUE(vol.ok()) << vol.status();
    EXPECT_EQ(vol->frame.resolution, (Int3{16, 16, 16}));
    ++previews;
  });
  ASSERT_TRUE(final_job.ok()) << final_job.status();
  EXPECT_EQ(final_job->state(), v1::JOB_STATE_SUCCEEDED) << final_job->error();
  EXPECT_TRUE(saw_running);
  EXPECT_GE(previews, 3);

  const auto out = dir_ / "tet.vdb";
  ASSERT_TRUE(server_->client().Fetch(job->id(), out).ok());
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
  ASSERT_TRUE(server_->client().Fetch(job->id(), resumed).ok());
  EXPECT_EQ(*Sha256File(resumed), final_job->result().sha256());
  // A corrupt partial download is detected and discarded.
  std::ofstream(dir_.path().string() + "/bad.vdb.part", std::ios::binary) << "garbage!";
  EXPECT_EQ(server_->client().Fetch(job->id(), dir_ / "bad.vdb").code(),
            absl::StatusCode::kDataLoss);
}

TEST_F(ServiceE2E, KilledServerRestartsTheJob) {
  auto job = server_->client().Submit(Tetrahedron(64, 800'000'000));
  ASSERT_TRUE(job.ok());
  WaitRunning(job->id());
  server_->Kill(SIGKILL);
  server_->Start();  // same data dir and port
  client::WatchOptions o;
  auto final_job = server_->client().Watch(job->id(), o, [](const v1::WatchJobResponse&) {});
  ASSERT_TRUE(final_job.ok()) << final_job.status();
  EXPECT_EQ(final_job->state(), v1::JOB_STATE_SUCCEEDED) << final_job->error();
  EXPECT_EQ(final_job->attempts(), 2u);
  ASSERT_TRUE(server_->client().Fetch(job->id(), dir_ / "after_restart.vdb").ok());
}

TEST_F(ServiceE2E, WatchSurvivesARestart) {
  auto job = server_->client().Submit(Tetrahedron(64, 800'000'000));
  ASSERT_TRUE(job.ok());
  bool restarted = false;
  client::WatchOptions o;
  // Its own client: the server fixture replaces its client on restart.
  auto watcher = NimbusClient::Connect(server_->target());
  auto final_job = watcher->Watch(job->id(), o, [&](const v1::WatchJobResponse& r) {
    if (!restarted && r.job().state() == v1::JOB_STATE_RUNNING && r.job().progress().done() > 0) {
      restarted = true;
      // Kill and restart while the stream is open; the watch must resume.
      server_->Kill(SIGKILL);
      server_->Start();
    }
  });
  ASSERT_TRUE(final_job.ok()) << final_job.status();
  EXPECT_TRUE(restarted);
  EXPECT_EQ(final_job->state(), v1::JOB_STATE_SUCCEEDED);
}

TEST_F(ServiceE2E, CancelStopsARunningJobWithinASecond) {
  auto job = server_->client().Submit(Tetrahedron(64, uint64_t{1} << 38));
  ASSERT_TRUE(job.ok());
  WaitRunning(job->id());
  // The result of an unfinished job is not there yet.
  EXPECT_EQ(server_->client().Fetch(job->id(), dir_ / "x.vdb").code(),
            absl::StatusCode::kFailedPrecondition);
  const auto start = Clock::now();
  auto cancelled = server_->client().Cancel(job->id());
  ASSERT_TRUE(cancelled.ok());
  v1::Job now;
  while (Clock::now() - start < std::chrono::seconds(5)) {
    now = *server_->client().Get(job->id());
    if (now.state() == v1::JOB_STATE_CANCELLED) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  const double seconds = std::chrono::duration<double>(Clock::now() - start).count();
  EXPECT_EQ(now.state(), v1::JOB_STATE_CANCELLED);
  EXPECT_LT(seconds, 1.0);
  // Watching a finished job returns its final state at once.
  auto watched = server_->client().Watch(job->id(), {}, [](const v1::WatchJobResponse&) {});
  ASSERT_TRUE(watched.ok());
  EXPECT_EQ(watched->state(), v1::JOB_STATE_CANCELLED);
}

TEST_F(ServiceE2E, ErrorCodes) {
  EXPECT_EQ(server_->client().Get("j-nope").status().code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(server_->client().Cancel("j-nope").status().code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(server_->client().Fetch("j-nope", dir_ / "n.vdb").code(), absl::StatusCode::kNotFound);

  v1::JobSpec bad = Tetrahedron(64, 10);
  bad.mutable_grid()->set_resolution(0, 0);
  auto s = server_->client().Submit(bad).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("grid.resolution[0]"), std::string::npos) << s;

  v1::JobSpec huge = Tetrahedron(4000, 10);
  s = server_->client().Submit(huge).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kResourceExhausted) << s;

  // Idempotent submit.
  auto a = server_->client().Submit(Tetrahedron(16, 1000), "req-1");
  auto b = server_->client().Submit(Tetrahedron(16, 1000), "req-1");
  ASSERT_TRUE(a.ok() && b.ok());
  EXPECT_EQ(a->id(), b->id());
  v1::ListJobsRequest req;
  auto list = server_->client().List(req);
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
