// Condensation sets end to end against a real nimbusd on loopback: asset
// uploads checked by sha256, set-IFS jobs from uploaded meshes, the book's
// frames, the non-watertight teapot's warning, and `nimbus render` uploading
// a spec's meshes by itself.
#include <gtest/gtest.h>

#include <cstdlib>
#include <fstream>
#include <optional>
#include <sstream>

#include "client/nimbus_client.h"
#include "core/base/sha256.h"
#include "core/io/vdb_io.h"
#include "proto/asset_paths.h"
#include "proto/spec_convert.h"
#include "tests/support/early_fetch.h"
#include "tests/support/fake_job_context.h"
#include "server/job_runner.h"
#include "proto/spec_io.h"
#include "tests/support/nimbusd_process.h"
#include "tests/support/server_fixture.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

using client::NimbusClient;

std::string ReadAll(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

class CondensationE2E : public testing::NimbusdTest {
 protected:
  // Submits and watches to the end.
  v1::Job Run(const v1::JobSpec& spec) {
    auto job = client_->Submit(spec);
    EXPECT_TRUE(job.ok()) << job.status();
    if (!job.ok()) return {};
    auto done = client_->Watch(job->id(), {}, [](const v1::WatchJobResponse&) {});
    EXPECT_TRUE(done.ok()) << done.status();
    return done.ok() ? *done : v1::Job{};
  }

};

TEST_F(CondensationE2E, UploadsAreCheckedAgainstTheirSha256) {
  const std::string cow = ReadAll(testing::SourcePath("examples/meshes/cow.obj"));
  const std::string sha = Sha256Hex(cow);
  auto first = client_->UploadBytes("cow.obj", cow, sha, cow.size());
  ASSERT_TRUE(first.ok()) << first.status();
  EXPECT_EQ(first->sha256(), sha);
  EXPECT_FALSE(first->already_present());
  auto again = client_->UploadBytes("cow.obj", cow, sha, cow.size());
  ASSERT_TRUE(again.ok()) << again.status();
  EXPECT_TRUE(again->already_present());

  // Bytes that do not hash to the announced value are refused.
  std::string altered = cow;
  altered[altered.size() / 2] ^= 1;
  auto wrong = client_->UploadBytes("cow.obj", altered, Sha256Hex(altered + "x"), altered.size());
  EXPECT_EQ(wrong.status().code(), absl::StatusCode::kDataLoss) << wrong.status();

  // A truncated upload (the stream ends early) is refused and not stored.
  const std::string head = altered.substr(0, altered.size() / 3);
  auto cut = client_->UploadBytes("cow.obj", head, Sha256Hex(altered), altered.size());
  EXPECT_EQ(cut.status().code(), absl::StatusCode::kInvalidArgument) << cut.status();
  EXPECT_NE(cut.status().message().find("truncated"), std::string::npos) << cut.status();

  v1::JobSpec spec = testing::LoadExample("cow_cloud.json");
  spec.mutable_grid()->set_resolution(0, 32);
  spec::ForEachAsset(spec,
                     [&](const std::string&, v1::Asset& a) { a.set_sha256(Sha256Hex(altered)); });
  auto refused = client_->Submit(spec);
  EXPECT_EQ(refused.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(refused.status().message().find("set_ifs.maps[0].condensation.mesh.asset.sha256"),
            std::string::npos)
      << refused.status();
}

TEST_F(CondensationE2E, NetworkServerRefusesLocalPaths) {
  v1::JobSpec spec = testing::LoadExample("cow_cloud.json");
  spec::ResolveAssetPaths(spec, testing::SourcePath("examples"));
  auto refused = client_->Submit(spec);
  EXPECT_EQ(refused.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(refused.status().message().find("upload"), std::string::npos) << refused.status();
}

TEST_F(CondensationE2E, CowCloudProducesAVdb) {
  v1::JobSpec spec = testing::LoadExample("cow_cloud.json");
  spec.mutable_grid()->set_resolution(0, 48);
  spec.mutable_set_ifs()->mutable_random()->set_iterations(300);
  ASSERT_TRUE(client_->UploadSpecAssets(spec, testing::SourcePath("examples")).ok());
  auto job = client_->Submit(spec);
  ASSERT_TRUE(job.ok()) << job.status();
  client::WatchOptions o;
  o.preview_resolution = 16;
  o.preview_interval_seconds = 0.05;
  int progress_updates = 0, previews = 0;
  auto done = client_->Watch(job->id(), o, [&](const v1::WatchJobResponse& r) {
    if (r.job().state() == v1::JOB_STATE_RUNNING) ++progress_updates;
    if (!r.has_preview()) return;
    auto vol = ReadVdbBytes(r.preview().vdb());
    ASSERT_TRUE(vol.ok()) << vol.status();
    EXPECT_EQ(vol->frame.resolution, (Int3{16, 16, 16}));
    ++previews;
  });
  ASSERT_TRUE(done.ok()) << done.status();
  ASSERT_EQ(done->state(), v1::JOB_STATE_SUCCEEDED) << done->error();
  EXPECT_GE(progress_updates, 2);
  EXPECT_GE(previews, 1);
  EXPECT_GT(done->stats().at("set_iterations"), 300u);
  EXPECT_EQ(done->progress().done(), done->progress().total());
  const auto out = dir_ / "cow.vdb";
  ASSERT_TRUE(client_->Fetch(job->id(), out).ok());
  auto vol = ReadVdbFile(out);
  ASSERT_TRUE(vol.ok()) << vol.status();
  EXPECT_EQ(vol->frame.resolution, (Int3{48, 48, 48}));
  float max = 0;
  int nonzero = 0;
  for (float v : vol->values) {
    max = std::max(max, v);
    nonzero += v > 0;
  }
  EXPECT_FLOAT_EQ(max, 1.0f);
  EXPECT_GT(nonzero, 500);  // a cow-sized cloud, not a speck
  // The server's result is exactly what the engine makes of the same spec
  // with the mesh read locally: upload, content addressing and the worker
  // change nothing.
  v1::JobSpec local = testing::LoadExample("cow_cloud.json");
  local.mutable_grid()->set_resolution(0, 48);
  local.mutable_set_ifs()->mutable_random()->set_iterations(300);
  spec::ResolveAssetPaths(local, testing::SourcePath("examples"));
  auto plan = spec::ConvertSpec(local, {});
  ASSERT_TRUE(plan.ok()) << plan.status();
  testing::FakeJobContext ctx;
  ASSERT_TRUE(server::RunJobPlan(*plan, ctx).ok());
  auto direct = ReadVdbFile(ctx.result());
  ASSERT_TRUE(direct.ok()) << direct.status();
  EXPECT_EQ(direct->values, vol->values);
  EXPECT_EQ(ctx.stats["set_iterations"], done->stats().at("set_iterations"));
}

TEST_F(CondensationE2E, CancelStopsASetIfsJob) {
  v1::JobSpec spec = testing::LoadExample("cow_cloud.json");
  spec.mutable_grid()->set_resolution(0, 64);
  spec.mutable_set_ifs()->mutable_random()->set_iterations(1'000'000);
  ASSERT_TRUE(client_->UploadSpecAssets(spec, testing::SourcePath("examples")).ok());
  auto job = client_->Submit(spec);
  ASSERT_TRUE(job.ok()) << job.status();
  // Cancel once the watch shows real progress; CancelJob answers when the
  // job has stopped (it waits up to 5 s, so a slow stop shows as RUNNING).
  auto other = NimbusClient::Connect(server_.target());
  std::optional<absl::StatusOr<v1::Job>> cancelled;
  auto done = client_->Watch(job->id(), {}, [&](const v1::WatchJobResponse& r) {
    if (!cancelled && r.job().state() == v1::JOB_STATE_RUNNING && r.job().progress().done() > 20)
      cancelled = other->Cancel(job->id());
  });
  ASSERT_TRUE(cancelled.has_value());
  ASSERT_TRUE(cancelled->ok()) << cancelled->status();
  EXPECT_EQ((*cancelled)->state(), v1::JOB_STATE_CANCELLED);
  EXPECT_EQ((*cancelled)->status().code(), 1);
  ASSERT_TRUE(done.ok());
  EXPECT_EQ(done->state(), v1::JOB_STATE_CANCELLED);
  EXPECT_EQ(done->status().code(), 1);
}

// A job that fails while running keeps its status code: its uploaded mesh
// disappears while it waits behind another job.
TEST_F(CondensationE2E, JobFailingAtRunTimeKeepsItsStatusCode) {
  auto tetrahedron = spec::LoadSpecFile(testing::SourcePath("examples/sierpinski_tetrahedron.json"));
  ASSERT_TRUE(tetrahedron.ok());
  tetrahedron->mutable_grid()->set_resolution(0, 64);
  tetrahedron->mutable_chaos_game()->set_iterations(uint64_t{1} << 38);
  auto busy = client_->Submit(*tetrahedron);  // one worker: holds the next job back
  ASSERT_TRUE(busy.ok()) << busy.status();
  v1::JobSpec spec = testing::LoadExample("cow_cloud.json");
  spec.mutable_grid()->set_resolution(0, 32);
  ASSERT_TRUE(client_->UploadSpecAssets(spec, testing::SourcePath("examples")).ok());
  auto job = client_->Submit(spec);
  ASSERT_TRUE(job.ok()) << job.status();
  EXPECT_EQ(job->state(), v1::JOB_STATE_QUEUED);
  std::filesystem::remove_all(dir_ / "data" / "assets");
  ASSERT_TRUE(client_->Cancel(busy->id()).ok());

  auto done = client_->Watch(job->id(), {}, [](const v1::WatchJobResponse&) {});
  ASSERT_TRUE(done.ok()) << done.status();
  ASSERT_EQ(done->state(), v1::JOB_STATE_FAILED) << done->DebugString();
  EXPECT_EQ(done->status().code(), int(absl::StatusCode::kInvalidArgument)) << done->error();
  EXPECT_EQ(done->status().message(), done->error());
  EXPECT_NE(done->error().find("no uploaded asset"), std::string::npos) << done->error();
  auto got = client_->Get(job->id());
  ASSERT_TRUE(got.ok());
  EXPECT_EQ(got->status().code(), int(absl::StatusCode::kInvalidArgument));
}

TEST_F(CondensationE2E, BookWritesOneFramePerPage) {
  v1::JobSpec spec = testing::LoadExample("morph_book.json");
  spec.mutable_grid()->set_resolution(0, 32);
  spec.mutable_set_ifs()->mutable_book()->set_depth(3);
  ASSERT_TRUE(client_->UploadSpecAssets(spec, testing::SourcePath("examples")).ok());
  const v1::Job done = Run(spec);
  ASSERT_EQ(done.state(), v1::JOB_STATE_SUCCEEDED) << done.error();
  auto full = client_->Get(done.id());
  ASSERT_TRUE(full.ok());
  ASSERT_EQ(full->result().files_size(), 8);
  for (int i = 0; i < 8; ++i)
    EXPECT_EQ(full->result().files(i).file_name(),
              "morph_book.000" + std::to_string(i + 1) + ".vdb");
  const auto out = dir_ / "page.vdb";
  ASSERT_TRUE(client_->Fetch(done.id(), out, "morph_book.0008.vdb").ok());
  EXPECT_EQ(*Sha256File(out), full->result().files(7).sha256());
  auto vol = ReadVdbFile(out);
  ASSERT_TRUE(vol.ok()) << vol.status();
  const MetaValue* address = vol->Find("nimbus_book_address");
  ASSERT_NE(address, nullptr);
  EXPECT_EQ(std::get<std::string>(*address), "BBB");
  EXPECT_EQ(client_->Fetch(done.id(), dir_ / "x.vdb", "nope.vdb").code(),
            absl::StatusCode::kNotFound);
}

// Pages are listed and can be fetched while later ones are still running.
TEST_F(CondensationE2E, BookFramesStreamWhileTheJobRuns) {
  v1::JobSpec spec = testing::LoadExample("morph_book.json");
  spec.mutable_grid()->set_resolution(0, 96);
  spec.mutable_set_ifs()->mutable_book()->set_depth(7);  // 128 pages
  ASSERT_TRUE(client_->UploadSpecAssets(spec, testing::SourcePath("examples")).ok());
  auto job = client_->Submit(spec);
  ASSERT_TRUE(job.ok()) << job.status();
  testing::EarlyFetch early;
  auto done = testing::WatchFetchingFirstFile(*client_, job->id(), dir_ / "early.vdb", early);
  ASSERT_TRUE(done.ok()) << done.status();
  ASSERT_EQ(done->state(), v1::JOB_STATE_SUCCEEDED) << done->error();
  EXPECT_EQ(early.fetched_while_running, 1);
  EXPECT_EQ(early.name, "morph_book.0001.vdb");
  const std::string first_sha = early.sha256;
  EXPECT_EQ(*Sha256File(dir_ / "early.vdb"), first_sha);
  auto full = client_->Get(job->id());
  ASSERT_TRUE(full.ok());
  ASSERT_EQ(full->result().files_size(), 128);
  EXPECT_EQ(full->result().files(0).sha256(), first_sha);  // the same page, committed
}

TEST_F(CondensationE2E, NonWatertightTeapotFinishesWithAWarning) {
  v1::JobSpec spec;
  spec.set_name("teapot");
  spec.mutable_grid()->add_resolution(32);
  v1::SetIfs* s = spec.mutable_set_ifs();
  s->add_maps()->mutable_condensation()->mutable_mesh()->mutable_asset()->set_path(
      testing::SourcePath("examples/meshes/teapot.obj").string());
  s->add_maps()->mutable_condensation()->mutable_sphere()->set_radius(0.3);
  s->mutable_random()->set_iterations(10);
  ASSERT_TRUE(client_->UploadSpecAssets(spec, "/").ok());
  const v1::Job done = Run(spec);
  ASSERT_EQ(done.state(), v1::JOB_STATE_SUCCEEDED) << done.error();
  ASSERT_GE(done.warnings_size(), 1);
  EXPECT_NE(done.warnings(0).find("not watertight"), std::string::npos) << done.warnings(0);
  // The warning names the artist's file, not only its hash.
  EXPECT_NE(done.warnings(0).find("teapot.obj (sha256 "), std::string::npos) << done.warnings(0);
}

TEST_F(CondensationE2E, DegenerateMeshIsAClearError) {
  const auto flat = dir_ / "flat.obj";
  std::ofstream(flat) << "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n";
  v1::JobSpec spec;
  spec.mutable_grid()->add_resolution(16);
  v1::SetIfs* s = spec.mutable_set_ifs();
  s->add_maps()->mutable_condensation()->mutable_sphere()->set_radius(0.5);
  s->add_maps()->mutable_condensation()->mutable_mesh()->mutable_asset()->set_path(flat.string());
  s->mutable_random()->set_iterations(10);
  // The upload itself is refused: the server checks a mesh (in a child
  // process) before it stores it, and says why, naming the file.
  const absl::Status up = client_->UploadSpecAssets(spec, "/");
  EXPECT_EQ(up.code(), absl::StatusCode::kInvalidArgument) << up;
  EXPECT_NE(up.message().find("degenerate"), std::string::npos) << up;
  EXPECT_NE(up.message().find("flat.obj"), std::string::npos) << up;
}

// `nimbus render` with its embedded server: relative mesh paths resolve
// against the spec's folder and are uploaded by the CLI; book frames land
// next to -o, named after it.
TEST_F(CondensationE2E, CliUploadsMeshesAndWritesFrames) {
  v1::JobSpec spec = testing::LoadExample("morph_book.json");
  spec.mutable_grid()->set_resolution(0, 24);
  spec.mutable_set_ifs()->mutable_book()->set_depth(2);
  std::filesystem::create_directories(dir_ / "job" / "meshes");
  for (const char* m : {"cow.obj", "suzanne.obj"})
    std::filesystem::copy_file(testing::SourcePath(std::string("examples/meshes/") + m),
                               dir_ / "job" / "meshes" / m);
  std::ofstream(dir_ / "job" / "book.json") << spec::SpecToJson(spec);
  std::filesystem::create_directories(dir_ / "out");
  const std::string cmd =
      std::string(NIMBUS_BIN_DIR) + "/nimbus --data-dir " + (dir_ / "cli").string() + " render " +
      (dir_ / "job" / "book.json").string() + " -o " + (dir_ / "out" / "morph.vdb").string() +
      " 2>" + (dir_ / "cli.log").string();
  ASSERT_EQ(std::system(cmd.c_str()), 0) << ReadAll(dir_ / "cli.log");
  EXPECT_TRUE(std::filesystem::exists(dir_ / "out" / "morph.vdb"));
  for (int i = 1; i <= 4; ++i)
    EXPECT_TRUE(std::filesystem::exists(dir_ / "out" / ("morph.000" + std::to_string(i) + ".vdb")))
        << ReadAll(dir_ / "cli.log");
}

}  // namespace
}  // namespace nimbus
