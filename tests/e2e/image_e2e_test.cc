// Pictures through a real nimbusd: preview PNGs arrive with the watch's
// preview grids, and the picture is a fetchable result file.
#include <gtest/gtest.h>

#include <fstream>

#include "core/io/image_io.h"
#include "tests/support/server_fixture.h"

namespace nimbus {
namespace {

class ImageE2E : public testing::NimbusdTest {};

TEST_F(ImageE2E, WatchersGetPreviewPicturesAndThePictureIsAResultFile) {
  v1::JobSpec spec = testing::LoadExample("arcs_image.json");
  spec.mutable_chaos_game()->set_iterations(60'000'000);
  spec.mutable_image()->set_width(200);
  spec.mutable_image()->set_preview_size(64);
  auto job = client_->Submit(spec);
  ASSERT_TRUE(job.ok()) << job.status();
  client::WatchOptions watch;
  watch.preview_resolution = 32;
  watch.preview_interval_seconds = 0.02;
  std::vector<v1::Preview> previews;
  auto done = client_->Watch(job->id(), watch, [&](const v1::WatchJobResponse& r) {
    if (r.has_preview()) previews.push_back(r.preview());
  });
  ASSERT_TRUE(done.ok()) << done.status();
  ASSERT_EQ(done->state(), v1::JOB_STATE_SUCCEEDED) << done->error();
  int pictures = 0;
  for (const v1::Preview& p : previews) {
    if (p.png().empty()) continue;  // the volume pass's previews have none
    ++pictures;
    std::ofstream(dir_ / "p.png", std::ios::binary) << p.png();
    auto png = ReadPngPixels(dir_ / "p.png");
    ASSERT_TRUE(png.ok()) << png.status();
    EXPECT_LE(std::max(png->width, png->height), 64);
    EXPECT_GT(std::max(png->width, png->height), 32);
    EXPECT_EQ(png->channels, 3);
    ASSERT_EQ(p.resolution_size(), 3);
    EXPECT_LE(std::max(p.resolution(0), p.resolution(1)), 32);
    EXPECT_EQ(p.resolution(2), 1);
  }
  EXPECT_GE(pictures, 1);
  ASSERT_TRUE(client_->Fetch(job->id(), dir_ / "arcs.png", "arcs_image.png").ok());
  auto png = ReadPngPixels(dir_ / "arcs.png");
  ASSERT_TRUE(png.ok()) << png.status();
  EXPECT_EQ(png->width, 200);
  ASSERT_TRUE(client_->Fetch(job->id(), dir_ / "arcs.vdb").ok());
}

}  // namespace
}  // namespace nimbus
