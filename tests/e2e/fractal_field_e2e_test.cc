// Fractal fields end to end against a real nimbusd on loopback: the wind
// loop's frames (listed and fetchable while the job runs, the main result
// equal to frame 1), a terrain's PNG height map, the shaped cumulus from an
// uploaded mesh, and a bad spec refused at submit with its field named.
#include <gtest/gtest.h>

#include "client/nimbus_client.h"
#include "core/base/sha256.h"
#include "core/io/png_io.h"
#include "core/io/vdb_io.h"
#include "proto/spec_io.h"
#include "tests/support/early_fetch.h"
#include "tests/support/nimbusd_process.h"
#include "tests/support/server_fixture.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

using client::NimbusClient;

class FractalFieldE2E : public testing::NimbusdTest {};

TEST_F(FractalFieldE2E, WindLoopFramesStreamWhileTheJobRuns) {
  v1::JobSpec spec = testing::LoadExample("wind_loop.json");
  // Many small frames, so some are listed before the last is done.
  spec.mutable_grid()->set_resolution(0, 48);
  spec.mutable_grid()->set_resolution(1, 48);
  spec.mutable_grid()->set_resolution(2, 16);
  spec.mutable_fractal_field()->mutable_animation()->set_frames(160);
  spec.mutable_fractal_field()->mutable_animation()->set_time_step(0.05);
  auto job = client_->Submit(spec);
  ASSERT_TRUE(job.ok()) << job.status();
  testing::EarlyFetch early;
  auto done = testing::WatchFetchingFirstFile(*client_, job->id(), dir_ / "early.vdb", early);
  ASSERT_TRUE(done.ok()) << done.status();
  ASSERT_EQ(done->state(), v1::JOB_STATE_SUCCEEDED) << done->error();
  EXPECT_EQ(early.fetched_while_running, 1);
  EXPECT_EQ(early.name, "wind_loop.0001.vdb");
  const std::string first_sha = early.sha256;
  EXPECT_EQ(*Sha256File(dir_ / "early.vdb"), first_sha);
  auto full = client_->Get(job->id());
  ASSERT_TRUE(full.ok());
  ASSERT_EQ(full->result().files_size(), 160);
  EXPECT_EQ(full->result().files(0).sha256(), first_sha);
  EXPECT_EQ(full->result().files(159).file_name(), "wind_loop.0160.vdb");
  // The main result is frame 1, byte for byte.
  ASSERT_TRUE(client_->Fetch(job->id(), dir_ / "main.vdb").ok());
  EXPECT_EQ(*Sha256File(dir_ / "main.vdb"), first_sha);
  auto last = dir_ / "last.vdb";
  ASSERT_TRUE(client_->Fetch(job->id(), last, "wind_loop.0160.vdb").ok());
  auto vol = ReadVdbFile(last);
  ASSERT_TRUE(vol.ok()) << vol.status();
  EXPECT_EQ(std::get<int64_t>(*vol->Find("nimbus_field_frame")), 160);
}

TEST_F(FractalFieldE2E, TerrainHasAPngHeightMap) {
  v1::JobSpec spec = testing::LoadExample("terrain.json");
  spec.mutable_grid()->set_resolution(0, 64);
  spec.mutable_grid()->set_resolution(1, 48);
  spec.mutable_grid()->set_resolution(2, 16);
  auto job = client_->Submit(spec);
  ASSERT_TRUE(job.ok()) << job.status();
  auto done = client_->Watch(job->id(), {}, [](const v1::WatchJobResponse&) {});
  ASSERT_TRUE(done.ok()) << done.status();
  ASSERT_EQ(done->state(), v1::JOB_STATE_SUCCEEDED) << done->error();
  ASSERT_TRUE(client_->Fetch(job->id(), dir_ / "h.png", "terrain.height.png").ok());
  auto png = ReadPng16(dir_ / "h.png");
  ASSERT_TRUE(png.ok()) << png.status();
  EXPECT_EQ(png->width, 64);
  EXPECT_EQ(png->height, 48);
  ASSERT_TRUE(client_->Fetch(job->id(), dir_ / "t.vdb").ok());
  auto surface = ReadVdbFile(dir_ / "t.vdb", "surface");
  ASSERT_TRUE(surface.ok()) << surface.status();
  EXPECT_EQ(surface->grid_class, "level set");
}

TEST_F(FractalFieldE2E, CumulusFromAnUploadedMesh) {
  v1::JobSpec spec = testing::LoadExample("cumulus.json");
  spec.mutable_grid()->set_resolution(0, 48);
  ASSERT_TRUE(client_->UploadSpecAssets(spec, testing::SourcePath("examples")).ok());
  auto job = client_->Submit(spec);
  ASSERT_TRUE(job.ok()) << job.status();
  auto done = client_->Watch(job->id(), {}, [](const v1::WatchJobResponse&) {});
  ASSERT_TRUE(done.ok()) << done.status();
  ASSERT_EQ(done->state(), v1::JOB_STATE_SUCCEEDED) << done->error();
  ASSERT_TRUE(client_->Fetch(job->id(), dir_ / "c.vdb").ok());
  auto vol = ReadVdbFile(dir_ / "c.vdb");
  ASSERT_TRUE(vol.ok()) << vol.status();
  int dense = 0;
  for (float v : vol->values) dense += v > 0.5f;
  EXPECT_GT(dense, 100);
  EXPECT_EQ(vol->At(0, 0, 0), 0.f);  // the corner is far outside the head
}

TEST_F(FractalFieldE2E, BadSpecIsRefusedAtSubmit) {
  v1::JobSpec spec = testing::LoadExample("wind_loop.json");
  spec.mutable_fractal_field()->mutable_field()->mutable_mesh_series()->set_count(65);
  auto job = client_->Submit(spec);
  ASSERT_EQ(job.status().code(), absl::StatusCode::kInvalidArgument) << job.status();
  EXPECT_EQ(job.status().message(), "fractal_field.field.mesh_series.count: must be 1..64, got 65");
}

}  // namespace
}  // namespace nimbus
