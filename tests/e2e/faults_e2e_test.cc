// Hostile jobs against a real nimbusd on loopback: a job that spends its
// time in warm-up still cancels at once, SIGTERM ends the server within its
// drain time whatever runs, absurd specs (meshes that fan out into huge
// work, degenerate fields, unchecked names) are refused at submit, and a
// full disk fails a job clearly.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <sys/mount.h>

#include <cerrno>
#include <chrono>
#include <cstring>
#include <fstream>
#include <future>

#include <grpcpp/grpcpp.h>

#include "absl/strings/str_cat.h"
#include "client/nimbus_client.h"
#include "core/base/sha256.h"
#include "nimbus/v1/nimbus_service.grpc.pb.h"
#include "proto/spec_io.h"
#include "tests/support/nimbusd_process.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

using client::NimbusClient;
using Clock = std::chrono::steady_clock;
using ::testing::HasSubstr;

// The largest warm-up allowed, on the slow (nonlinear) path, over many
// chunks: each chunk is 16 million warm-up steps before its first point.
v1::JobSpec WarmupHeavy() {
  auto spec = spec::LoadSpecFile(testing::SourcePath("examples/sierpinski_tetrahedron.json"));
  EXPECT_TRUE(spec.ok());
  spec->mutable_grid()->set_resolution(0, 32);
  auto* cg = spec->mutable_chaos_game();
  cg->set_iterations(uint64_t{1} << 32);
  cg->set_warmup(1'000'000);
  for (auto& m : *cg->mutable_ifs()->mutable_maps()) {
    auto* v = m.add_variations();
    v->set_name("sinusoidal");
    v->set_weight(0.5);
  }
  return *spec;
}

v1::JobSpec Parse(const std::string& json) {
  auto spec = spec::ParseSpec(json, spec::SpecFormat::kJson);
  EXPECT_TRUE(spec.ok()) << spec.status();
  return spec.ok() ? *spec : v1::JobSpec();
}

// A set IFS condensing onto the uploaded mesh `sha256`, fitted to the grid.
v1::JobSpec MeshJob(const std::string& sha256, int resolution) {
  return Parse(absl::StrCat(R"({"name": "m", "grid": {"resolution": [)", resolution,
                            R"(]}, "set_ifs": {"maps": [{"condensation": {"mesh": {"asset": )",
                            R"({"sha256": ")", sha256,
                            R"(", "label": "m.obj"}}}}], "random": {"iterations": "3"}}})"));
}

// Three corners of a slanted triangle, then `lines` faces of `corners`
// corners that go round it again and again: the fan of each face holds
// (corners - 2) / 3 copies of the whole triangle.
std::string FanningObj(int lines, int corners) {
  std::string obj = "v 0 0 0\nv 1 0.2 0.3\nv 0.3 1 0.6\n";
  for (int l = 0; l < lines; ++l) {
    obj += "f";
    for (int c = 0; c < corners; ++c) absl::StrAppend(&obj, " ", c % 3 + 1);
    obj += "\n";
  }
  return obj;
}

class FaultsE2E : public ::testing::Test {
 protected:
  void Start(std::vector<std::string> more) {
    std::vector<std::string> args = {"--workers", "1", "--threads-per-job", "2", "--log-level",
                                     "warn", "--min-free-disk-mib", "0"};
    args.insert(args.end(), more.begin(), more.end());
    server_.set_args(args);
    const absl::Status s = server_.Start();
    ASSERT_TRUE(s.ok()) << s;
    client_ = NimbusClient::Connect(server_.target());
    ASSERT_TRUE(client_->WaitForReady(20).ok()) << "nimbusd did not answer";
  }

  // Submits `spec` and returns its id once a worker runs it: reads the
  // job's watch stream (events) until RUNNING, under a guard deadline.
  std::string SubmitAndAwaitRunning(const v1::JobSpec& spec) {
    auto job = client_->Submit(spec);
    EXPECT_TRUE(job.ok()) << job.status();
    if (!job.ok()) return "";
    auto stub = v1::NimbusService::NewStub(
        grpc::CreateChannel(server_.target(), grpc::InsecureChannelCredentials()));
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(60));
    v1::WatchJobRequest req;
    req.set_job_id(job->id());
    auto reader = stub->WatchJob(&ctx, req);
    v1::WatchJobResponse r;
    bool running = false;
    while (!running && reader->Read(&r)) running = r.job().state() == v1::JOB_STATE_RUNNING;
    ctx.TryCancel();
    reader->Finish();
    EXPECT_TRUE(running) << "the job never ran";
    return running ? job->id() : "";
  }

  // Uploads `bytes` as `name` and returns the sha256 (empty on failure).
  std::string Upload(const std::string& name, const std::string& bytes) {
    const std::string sha = Sha256Hex(bytes);
    auto up = client_->UploadBytes(name, bytes, sha, bytes.size());
    EXPECT_TRUE(up.ok()) << up.status();
    return up.ok() ? sha : "";
  }

  // Submits `spec`; a job that should have been refused is cancelled at once.
  absl::Status Refusal(const v1::JobSpec& spec) {
    auto job = client_->Submit(spec);
    if (job.ok()) (void)client_->Cancel(job->id());
    return job.status();
  }

  // Puts the data folder's results/ on a tmpfs of `size` ("8m"), the job
  // database staying on the normal disk, so only result writes meet a full
  // disk; false where this process may not mount. Unmounted after the test.
  bool ResultsOnTmpfs(const std::string& size) {
    std::filesystem::create_directories(tiny_);
    if (::mount("tmpfs", tiny_.c_str(), "tmpfs", 0, ("size=" + size).c_str()) != 0) return false;
    mounted_ = true;
    std::filesystem::create_directories(tiny_ / "results" / "scratch");
    std::filesystem::create_directories(dir_ / "data");
    std::filesystem::create_directory_symlink(tiny_ / "results", dir_ / "data" / "results");
    return true;
  }
  void TearDown() override {
    if (mounted_) ::umount2(tiny_.c_str(), MNT_DETACH);
  }

  testing::TempDir dir_;
  testing::NimbusdProcess server_{dir_ / "data"};
  std::unique_ptr<NimbusClient> client_;
  const std::filesystem::path tiny_ = dir_ / "tiny";
  bool mounted_ = false;
};

TEST_F(FaultsE2E, WarmupHeavyJobCancelsPromptly) {
  // CancelJob answers CANCELLED only if the job stops within the wait.
  Start({"--cancel-wait-ms", "30000"});
  const std::string id = SubmitAndAwaitRunning(WarmupHeavy());
  ASSERT_FALSE(id.empty());
  auto cancelled = client_->Cancel(id);
  ASSERT_TRUE(cancelled.ok()) << cancelled.status();
  EXPECT_EQ(cancelled->state(), v1::JOB_STATE_CANCELLED);
  EXPECT_EQ(cancelled->status().code(), 1);  // google.rpc.Code CANCELLED
}

TEST_F(FaultsE2E, SigtermEndsTheServerWithinItsDrainTime) {
  constexpr int kDrainMs = 2000;
  Start({"--drain-ms", std::to_string(kDrainMs)});
  const std::string id = SubmitAndAwaitRunning(WarmupHeavy());
  ASSERT_FALSE(id.empty());
  const auto t0 = Clock::now();
  auto stopped = std::async(std::launch::async, [this] { return server_.Stop(); });
  // Guard only; the bound is asserted on the measured time below.
  if (stopped.wait_for(std::chrono::seconds(60)) != std::future_status::ready) {
    server_.Kill();
    FAIL() << "nimbusd ignored SIGTERM for a minute";
  }
  const double seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  EXPECT_EQ(stopped.get(), 0) << "nimbusd did not stop cleanly";
  EXPECT_LT(seconds, kDrainMs / 1000.0 + 3) << "a bound on stopping, not a speed claim";

  // The interrupted job went back to the queue and runs again.
  Start({"--cancel-wait-ms", "30000"});
  auto job = client_->Get(id);
  ASSERT_TRUE(job.ok()) << job.status();
  EXPECT_TRUE(job->state() == v1::JOB_STATE_QUEUED || job->state() == v1::JOB_STATE_RUNNING)
      << v1::JobState_Name(job->state());
  EXPECT_TRUE(client_->Cancel(id).ok());
}

TEST_F(FaultsE2E, AbsurdSpecsAreRefusedAtSubmitByFieldName) {
  Start({});
  auto spec = WarmupHeavy();
  spec.mutable_chaos_game()->set_warmup(4294967295u);
  auto job = client_->Submit(spec);
  ASSERT_FALSE(job.ok());
  EXPECT_EQ(job.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(job.status().message(), HasSubstr("chaos_game.warmup"));

  spec = WarmupHeavy();
  spec.mutable_chaos_game()->mutable_ifs()->set_probability_mode(v1::ProbabilityMode(99));
  job = client_->Submit(spec);
  ASSERT_FALSE(job.ok());
  EXPECT_THAT(job.status().message(), HasSubstr("chaos_game.ifs.probability_mode"));

  spec = WarmupHeavy();
  spec.mutable_grid()->mutable_bounds_max()->set_x(1e308);
  job = client_->Submit(spec);
  ASSERT_FALSE(job.ok());
  EXPECT_THAT(job.status().message(), HasSubstr("grid.bounds_max.x"));
}

v1::JobSpec Tetrahedron(int resolution, uint64_t iterations) {
  auto spec = spec::LoadSpecFile(testing::SourcePath("examples/sierpinski_tetrahedron.json"));
  EXPECT_TRUE(spec.ok());
  spec->mutable_grid()->set_resolution(0, resolution);
  spec->mutable_chaos_game()->set_iterations(iterations);
  return *spec;
}

// Fills the file system of `dir`, leaving about `keep` bytes free.
void FillLeaving(const std::filesystem::path& dir, uint64_t keep) {
  const std::filesystem::space_info space = std::filesystem::space(dir);
  std::ofstream out(dir / "filler", std::ios::binary);
  const std::string block(4096, 'x');
  for (uint64_t left = space.available > keep ? space.available - keep : 0; left >= block.size();
       left -= block.size())
    if (!out.write(block.data(), std::streamsize(block.size()))) break;
}

// results/ on a 8 MiB tmpfs (the job database stays on the normal disk,
// so only the result write meets the full disk).
TEST_F(FaultsE2E, FullDiskFailsTheJobClearlyAndKeepsServingReads) {
  if (!ResultsOnTmpfs("8m"))
    GTEST_SKIP() << "cannot mount a tmpfs here (" << std::strerror(errno) << ")";
  const std::filesystem::path& mnt = tiny_;
  Start({"--cancel-wait-ms", "30000"});

  auto small = client_->Submit(Tetrahedron(32, 100'000));
  ASSERT_TRUE(small.ok()) << small.status();
  auto small_done = client_->Watch(small->id(), {}, [](const v1::WatchJobResponse&) {});
  ASSERT_TRUE(small_done.ok() && small_done->state() == v1::JOB_STATE_SUCCEEDED);

  FillLeaving(mnt, 600 << 10);
  auto big = client_->Submit(Tetrahedron(200, 80'000'000));
  ASSERT_TRUE(big.ok()) << big.status();
  auto big_done = client_->Watch(big->id(), {}, [](const v1::WatchJobResponse&) {});
  ASSERT_TRUE(big_done.ok()) << big_done.status();
  EXPECT_EQ(big_done->state(), v1::JOB_STATE_FAILED);
  EXPECT_EQ(big_done->status().code(), int(absl::StatusCode::kResourceExhausted));
  EXPECT_THAT(big_done->error(), HasSubstr("disk full while writing the result"));
  // Nothing of the failed job is left, in results/ or its scratch.
  std::vector<std::string> names;
  for (const auto& e : std::filesystem::recursive_directory_iterator(mnt / "results"))
    if (e.is_regular_file()) names.push_back(e.path().filename().string());
  EXPECT_EQ(names, std::vector<std::string>{small->id() + ".vdb"});

  // Restarted on the full disk, the server still answers and serves files.
  server_.Stop();
  std::ofstream(mnt / "filler", std::ios::app) << std::string(1 << 20, 'x');
  Start({});
  auto got = client_->Get(big->id());
  ASSERT_TRUE(got.ok()) << got.status();
  EXPECT_EQ(got->state(), v1::JOB_STATE_FAILED);
  ASSERT_TRUE(client_->Fetch(small->id(), dir_ / "small.vdb").ok());
  EXPECT_EQ(*Sha256File(dir_ / "small.vdb"), small_done->result().sha256());
}

TEST_F(FaultsE2E, APolygonOfAMillionCornersIsRefusedByName) {
  Start({});
  const std::string obj = FanningObj(1, 1'000'000);
  // Named .obj, the upload itself is read and refused.
  auto up = client_->UploadBytes("poly.obj", obj, Sha256Hex(obj), obj.size());
  ASSERT_FALSE(up.ok());
  EXPECT_EQ(up.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(up.status().message(), HasSubstr("face has 1000000 corners; at most 4096"));
  // Without a format in its name it is stored; the spec that uses it is refused.
  const std::string sha = Upload("poly", obj);
  ASSERT_FALSE(sha.empty());
  const absl::Status st = Refusal(MeshJob(sha, 32));
  EXPECT_EQ(st.code(), absl::StatusCode::kInvalidArgument) << st;
  EXPECT_THAT(st.message(), HasSubstr("set_ifs.maps[0].condensation.mesh.asset: mesh asset m.obj"));
  EXPECT_THAT(st.message(), HasSubstr("face has 1000000 corners; at most 4096"));
}

// 100 faces of 4096 corners, 800 KB: 136,500 copies of a triangle across a
// 64^3 grid. Each copy meets about 1,500 lattice rays of an axis, so the
// ray vote alone would hold some 2.4 GB of crossings.
TEST_F(FaultsE2E, ASmallMeshThatFansOutIsPricedAtAdmission) {
  Start({"--max-memory-gib", "1"});
  const std::string sha = Upload("fan.obj", FanningObj(100, 4096));
  ASSERT_FALSE(sha.empty());
  const absl::Status st = Refusal(MeshJob(sha, 64));
  EXPECT_EQ(st.code(), absl::StatusCode::kResourceExhausted) << st;
  EXPECT_THAT(st.message(), HasSubstr("set_ifs.maps[0].condensation: voxelising its mesh"));
  EXPECT_THAT(st.message(), HasSubstr("the server limit is 1.00 GiB"));
  // One face of the same triangle is an ordinary small job.
  const std::string one = Upload("one.obj", FanningObj(1, 3));
  auto job = client_->Submit(MeshJob(one, 64));
  ASSERT_TRUE(job.ok()) << job.status();
  auto done = client_->Watch(job->id(), {}, [](const v1::WatchJobResponse&) {});
  ASSERT_TRUE(done.ok()) << done.status();
  EXPECT_EQ(done->state(), v1::JOB_STATE_SUCCEEDED) << done->error();
}

TEST_F(FaultsE2E, DegenerateFieldsAndGridNamesAreRefusedByField) {
  Start({});
  const std::string field = R"({"name": "f", "grid": {"resolution": [16]}, "fractal_field": {
      "field": {"dimensions": 4, "mesh_series": {"base_cell_size": [0.5], "ratio": 0.5,
                "count": 2}, WEIGHTS "mapping": {"wind": {"kind": "WIND_KIND_SINE",
                "amplitude": [0.3], "period": 1}}},
      "animation": {"frames": 2}}})";
  auto with = [&](const std::string& weights) {
    std::string json = field;
    json.replace(json.find("WEIGHTS"), 7, weights);
    return Parse(json);
  };
  v1::JobSpec spec = with("");
  spec.mutable_fractal_field()->mutable_field()->mutable_mapping()->mutable_wind()->set_period(
      1e-320);
  absl::Status st = Refusal(spec);
  EXPECT_EQ(st.code(), absl::StatusCode::kInvalidArgument) << st;
  EXPECT_THAT(st.message(), HasSubstr("fractal_field.field.mapping.wind.period: must be in"));
  st = Refusal(with(R"("weights": {"rule": "WEIGHT_RULE_EXPLICIT", "explicit_weights": [0, 0]},)"));
  EXPECT_EQ(st.code(), absl::StatusCode::kInvalidArgument) << st;
  EXPECT_THAT(st.message(), HasSubstr("fractal_field.field.weights.explicit_weights: need at "
                                      "least one weight that is not 0"));

  spec = with("");
  spec.mutable_output()->set_grid_name(std::string(1 << 20, 'g'));
  st = Refusal(spec);
  EXPECT_EQ(st.code(), absl::StatusCode::kInvalidArgument) << st;
  EXPECT_THAT(st.message(), HasSubstr("output.grid_name"));
  spec.mutable_output()->set_grid_name(std::string("../x\0y", 6));
  st = Refusal(spec);
  EXPECT_EQ(st.code(), absl::StatusCode::kInvalidArgument) << st;
  EXPECT_THAT(st.message(), HasSubstr("output.grid_name: use letters, digits"));
}

// A result too big to keep its encoded leaves in memory (over 4 MiB) on a
// 2 MiB results disk: the leaves' spill file fills it before the .vdb is
// written. The client reads the documented code and message, and no
// server path.
TEST_F(FaultsE2E, FullDiskUnderASpillingResultIsResourceExhaustedWithoutPaths) {
  if (!ResultsOnTmpfs("2m"))
    GTEST_SKIP() << "cannot mount a tmpfs here (" << std::strerror(errno) << ")";
  Start({});
  // Eight half-size copies fill the cube: every voxel of 160^3 is hit.
  v1::JobSpec spec = WarmupHeavy();
  spec.mutable_grid()->set_resolution(0, 160);
  auto* cg = spec.mutable_chaos_game();
  cg->set_iterations(40'000'000);
  cg->set_warmup(0);
  cg->mutable_ifs()->clear_maps();
  for (int m = 0; m < 8; ++m) {
    auto* steps = cg->mutable_ifs()->add_maps()->mutable_steps();
    auto* t = steps->Add()->mutable_translate();
    t->set_x(m & 1 ? 0.5 : -0.5), t->set_y(m & 2 ? 0.5 : -0.5), t->set_z(m & 4 ? 0.5 : -0.5);
    steps->Add()->mutable_scale()->set_uniform(0.5);
  }
  auto job = client_->Submit(spec);
  ASSERT_TRUE(job.ok()) << job.status();
  auto done = client_->Watch(job->id(), {}, [](const v1::WatchJobResponse&) {});
  ASSERT_TRUE(done.ok()) << done.status();
  EXPECT_EQ(done->state(), v1::JOB_STATE_FAILED);
  EXPECT_EQ(done->status().code(), int(absl::StatusCode::kResourceExhausted)) << done->error();
  EXPECT_THAT(done->error(), HasSubstr("disk full while writing the result"));
  EXPECT_THAT(done->error(), ::testing::Not(HasSubstr(dir_.path().string())));
  EXPECT_THAT(done->error(), ::testing::Not(HasSubstr("scratch/")));
}

}  // namespace
}  // namespace nimbus
