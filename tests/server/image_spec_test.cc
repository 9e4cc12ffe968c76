// JobSpec.image and grid.auto_frame: validation that names the field before
// anything is allocated, and the runner writing pictures as result files.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "absl/strings/str_cat.h"
#include "core/io/image_io.h"
#include "core/io/vdb_io.h"
#include "proto/spec_convert.h"
#include "proto/spec_io.h"
#include "server/job_runner.h"
#include "server/result_store.h"
#include "tests/support/fake_job_context.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

using ::testing::HasSubstr;

// A flat Sierpinski triangle with an `image` message (JSON body).
std::string Spec(const std::string& image, const std::string& grid_extra = "",
                 const std::string& cg_extra = "") {
  return absl::StrCat(R"({"name": "tri", "grid": {"resolution": [32, 32, 4],
      "bounds_min": {"x": -0.1, "y": -0.1, "z": -0.1},
      "bounds_max": {"x": 1.1, "y": 1.1, "z": 0.1})",
                      grid_extra, R"(},
    "chaos_game": {"ifs": {"maps": [
        {"steps": [{"scale": {"uniform": 0.5}}]},
        {"steps": [{"translate": {"x": 0.5}}, {"scale": {"uniform": 0.5}}]},
        {"steps": [{"translate": {"y": 0.5}}, {"scale": {"uniform": 0.5}}]}]},
      "iterations": "3000000", "seed": "2")",
                      cg_extra, R"(},
    "image": )",
                      image, "}");
}

absl::StatusOr<JobPlan> Convert(const std::string& json) {
  auto spec = spec::ParseSpec(json, spec::SpecFormat::kJson);
  if (!spec.ok()) return spec.status();
  return spec::ConvertSpec(*spec, spec::Limits{});
}

void ExpectError(const std::string& image, const std::string& field,
                 absl::StatusCode code = absl::StatusCode::kInvalidArgument) {
  auto plan = Convert(Spec(image));
  ASSERT_FALSE(plan.ok()) << image;
  EXPECT_EQ(plan.status().code(), code) << plan.status();
  EXPECT_THAT(std::string(plan.status().message()), HasSubstr(field)) << image;
}

TEST(ImageSpec, BadValuesNameTheirField) {
  ExpectError(R"({"width": 0})", "image.width");
  ExpectError(R"({"width": 70000})", "image.width");
  ExpectError(R"({"width": 64, "height": -1})", "image.height");
  ExpectError(R"({"width": 64, "supersample": 9})", "image.supersample");
  ExpectError(R"({"width": 64, "look": {"desaturation": 150}})", "image.look.desaturation");
  ExpectError(R"({"width": 64, "look": {"glow": -5}})", "image.look.glow");
  ExpectError(R"({"width": 64, "look": {"glow_radius": 1000}})", "image.look.glow_radius");
  ExpectError(R"({"width": 64, "look": {"gamma": 50}})", "image.look.gamma");
  ExpectError(R"({"width": 64, "look": {"brightness": -1}})", "image.look.brightness");
  ExpectError(R"({"width": 64, "look": {"background": {"x": 2}}})", "image.look.background.x");
  ExpectError(R"({"width": 64, "preview_size": 4})", "image.preview_size");
  ExpectError(R"({"width": 64, "camera": {"look_at": {"z": 1}, "position": {"z": 1}}})",
              "image.camera.look_at");
  ExpectError(R"({"width": 64, "camera": {"position": {"y": 3}, "up": {"y": 1}}})",
              "image.camera.up");
  ExpectError(R"({"width": 64, "axis": "PROJECTION_AXIS_X",
                  "camera": {"position": {"z": 3}}})",
              "image.axis");
  ExpectError(R"({"width": 64, "camera": {"kind": "CAMERA_KIND_PERSPECTIVE",
                  "position": {"z": 3}, "fov": 180}})",
              "image.camera.fov");
  // An absurd size is refused before anything is allocated.
  ExpectError(R"({"width": 65536, "height": 65536, "supersample": 8})", "2^30",
              absl::StatusCode::kResourceExhausted);
  auto bad_frame = Convert(Spec(R"({"width": 64})", R"(, "auto_frame": {"enabled": true,
      "margin": 3})"));
  ASSERT_FALSE(bad_frame.ok());
  EXPECT_THAT(std::string(bad_frame.status().message()), HasSubstr("grid.auto_frame.margin"));
  auto splat = Convert(Spec(R"({"width": 64})", "", R"(, "splat": true)"));
  ASSERT_FALSE(splat.ok());
  EXPECT_THAT(std::string(splat.status().message()), HasSubstr("chaos_game.splat"));
}

TEST(ImageSpec, DefaultsAndTheLook) {
  auto plan = Convert(Spec(R"({"width": 64, "look": {"desaturation": 30, "glow": 50}})", "",
                           R"(, "color": {})"));
  ASSERT_TRUE(plan.ok()) << plan.status();
  const ImageJob& im = *plan->chaos_game()->image;
  EXPECT_EQ(im.supersample, 1);
  EXPECT_EQ(im.format, ImageFormat::kPng8);
  EXPECT_EQ(im.look.tone, ToneMapping::kSqrt);
  EXPECT_DOUBLE_EQ(im.look.desaturation, 0.3);
  EXPECT_DOUBLE_EQ(im.look.glow, 0.5);
  EXPECT_TRUE(im.look.colored);
  EXPECT_TRUE(im.look.palette.is_sine());
  EXPECT_EQ(plan->work.total, 6'000'000u);  // picture and volume
}

TEST(ImageRunner, ImageOnlyMakesThePictureTheResult) {
  auto plan = Convert(Spec(R"({"width": 120, "supersample": 2, "image_only": true,
      "format": "IMAGE_FORMAT_PNG16"})",
                           "", R"(, "color": {})"));
  ASSERT_TRUE(plan.ok()) << plan.status();
  testing::FakeJobContext ctx;
  ASSERT_TRUE(server::RunJobPlan(*plan, ctx).ok());
  EXPECT_TRUE(ctx.progress_ordered);
  auto png = ReadPngPixels(ctx.result());
  ASSERT_TRUE(png.ok()) << png.status();
  EXPECT_EQ(png->width, 120);
  EXPECT_EQ(png->height, 120);  // the square box's aspect
  EXPECT_EQ(png->bit_depth, 16);
  uint64_t lit = 0;
  for (uint16_t s : png->samples) lit += s > 0;
  EXPECT_GT(lit, 1000u);
}

TEST(ImageRunner, PictureBesideTheVolumeWithAutoFrame) {
  auto plan = Convert(Spec(R"({"width": 50, "height": 40, "format": "IMAGE_FORMAT_EXR"})",
                           R"(, "auto_frame": {"enabled": true, "margin": 0.02})"));
  ASSERT_TRUE(plan.ok()) << plan.status();
  testing::FakeJobContext ctx;
  ASSERT_TRUE(server::RunJobPlan(*plan, ctx).ok());
  EXPECT_TRUE(ctx.progress_ordered);
  auto exr = ReadExr(server::ExtraFilesDir(ctx.result()) / "tri.exr");
  ASSERT_TRUE(exr.ok()) << exr.status();
  EXPECT_EQ(exr->width, 50);
  EXPECT_EQ(exr->height, 40);
  auto grids = ReadVdbFile(ctx.result());
  ASSERT_TRUE(grids.ok()) << grids.status();
}

}  // namespace
}  // namespace nimbus
