// JobSpec.image and grid.auto_frame: validation that names the field before
// anything is allocated, and the runner writing pictures as result files.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>

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

// Two near-constant maps chosen 80 % and 20 % of the time light two pixels
// of a 2 x 2 grey picture with densities in the ratio 4 : 1 (N = 10^6
// points: the counts are 800 000 and 200 000 to within 0.2 %). The spec's
// tone mapping, worked by hand, gives the dimmer pixel
//   LOG    ln(1 + 200 000) / ln(1 + 800 000) = 0.898,
//   LINEAR 1/4,   GAMMA 2.2: (1/4)^(1/2.2) = 0.533,   SQRT: 0 (the faintest);
// the brighter one is 1.
TEST(ImageRunner, TheSpecsToneMappingShadesThePicture) {
  struct Case {
    const char* tone;
    double dim;
  };
  for (const Case c : {Case{"TONE_MAPPING_LOG", std::log(200001.0) / std::log(800001.0)},
                       Case{"TONE_MAPPING_LINEAR", 0.25},
                       Case{"TONE_MAPPING_GAMMA", std::pow(0.25, 1 / 2.2)},
                       Case{"TONE_MAPPING_SQRT", 0}}) {
    SCOPED_TRACE(c.tone);
    auto plan = Convert(absl::StrCat(R"({"name": "two", "grid": {"resolution": [8, 8, 2],
        "bounds_min": {"x": 0, "y": 0, "z": -0.1}, "bounds_max": {"x": 1, "y": 1, "z": 0.1}},
      "chaos_game": {"ifs": {"probability_mode": "PROBABILITY_MODE_EXPLICIT", "maps": [
          {"probability": 0.8, "steps": [{"translate": {"x": 0.25, "y": 0.25}},
                                         {"scale": {"uniform": 0.001}}]},
          {"probability": 0.2, "steps": [{"translate": {"x": 0.75, "y": 0.75}},
                                         {"scale": {"uniform": 0.001}}]}]},
        "iterations": "1000000", "seed": "3"},
      "image": {"width": 2, "height": 2, "image_only": true, "format": "IMAGE_FORMAT_PNG16",
                "look": {"tone_mapping": ")",
                                     c.tone, R"("}}})"));
    ASSERT_TRUE(plan.ok()) << plan.status();
    testing::FakeJobContext ctx;
    ASSERT_TRUE(server::RunJobPlan(*plan, ctx).ok());
    auto png = ReadPngPixels(ctx.result());
    ASSERT_TRUE(png.ok()) << png.status();
    ASSERT_EQ(png->width * png->height, 4);
    std::vector<double> v;
    for (int p = 0; p < 4; ++p) {
      uint16_t top = 0;
      for (int k = 0; k < png->channels; ++k)
        top = std::max(top, png->samples[size_t(p * png->channels + k)]);
      v.push_back(top / 65535.0);
    }
    std::sort(v.rbegin(), v.rend());
    EXPECT_NEAR(v[0], 1, 1e-9);
    EXPECT_NEAR(v[1], c.dim, 2e-3);
    EXPECT_EQ(v[2], 0);
    EXPECT_EQ(v[3], 0);
  }
}

}  // namespace
}  // namespace nimbus
