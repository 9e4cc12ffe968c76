// JobSpec.explore: every bad field named before anything is allocated, the
// candidates' specs converting to exactly the explored IFS, and the runner
// writing the contact sheet and the specs as result files.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <fstream>
#include <sstream>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/grid/contact_sheet.h"
#include "core/io/image_io.h"
#include "proto/explore_candidate.h"
#include "proto/spec_convert.h"
#include "proto/spec_io.h"
#include "server/job_runner.h"
#include "server/memory_admission.h"
#include "server/result_store.h"
#include "tests/support/fake_job_context.h"

namespace nimbus {
namespace {

using ::testing::HasSubstr;

absl::StatusOr<JobPlan> Convert(const std::string& explore, const std::string& extra = "") {
  auto spec = spec::ParseSpec(absl::StrCat(R"({"name": "ex", "explore": )", explore, extra, "}"),
                              spec::SpecFormat::kJson);
  if (!spec.ok()) return spec.status();
  return spec::ConvertSpec(*spec, spec::Limits{});
}

void ExpectError(const std::string& explore, const std::string& field,
                 absl::StatusCode code = absl::StatusCode::kInvalidArgument,
                 const std::string& extra = "") {
  auto plan = Convert(explore, extra);
  ASSERT_FALSE(plan.ok()) << explore;
  EXPECT_EQ(plan.status().code(), code) << plan.status();
  EXPECT_THAT(std::string(plan.status().message()), HasSubstr(field)) << explore;
}

TEST(ExploreSpec, BadValuesNameTheirField) {
  ExpectError(R"({"count": -1})", "explore.count");
  ExpectError(R"({"count": 5000})", "explore.count");
  ExpectError(R"({"dimensions": 4})", "explore.dimensions");
  ExpectError(R"({"min_maps": 1})", "explore.min_maps");
  ExpectError(R"({"max_maps": 40})", "explore.max_maps");
  ExpectError(R"({"min_maps": 6, "max_maps": 4})", "explore.max_maps");
  ExpectError(R"({"coefficient_range": -1})", "explore.coefficient_range");
  ExpectError(R"({"translation_range": 1e300})", "explore.translation_range");
  ExpectError(R"({"threshold": 1.5})", "explore.threshold");
  ExpectError(R"({"threshold": -0.5})", "explore.threshold");
  ExpectError(R"({"measure": "CONTRACTION_MEASURE_DETERMINANT", "threshold": 20})",
              "explore.threshold");
  ExpectError(R"({"measure": 7})", "explore.measure");
  ExpectError(R"({"count": 10, "max_attempts": 5})", "explore.max_attempts");
  ExpectError(R"({"max_attempts": "20000000"})", "explore.max_attempts");
  ExpectError(R"({"variations": ["nonsense"]})", "explore.variations[0]");
  ExpectError(R"({"variations": ["swirl", "julian"]})", "explore.variations[1]");
  ExpectError(R"({"variation_probability": 0.5})", "explore.variation_probability");
  ExpectError(R"({"variations": ["swirl"], "variation_probability": 2})",
              "explore.variation_probability");
  ExpectError(R"({"thumbnail_size": 8})", "explore.thumbnail_size");
  ExpectError(R"({"thumbnail_size": 4096})", "explore.thumbnail_size");
  ExpectError(R"({"thumbnail_iterations": "100"})", "explore.thumbnail_iterations");
  ExpectError(R"({"thumbnail_iterations": "1000000000"})", "explore.thumbnail_iterations");
  ExpectError(R"({"min_coverage": 0.9})", "explore.min_coverage");
  ExpectError(R"({"columns": 100})", "explore.columns");
  ExpectError(R"({"color_blend": 1.5})", "explore.color_blend");
  ExpectError(R"({"look": {"glow": 900}})", "explore.look.glow");
  ExpectError(R"({"candidate": {"width": 8}})", "explore.candidate.width");
  ExpectError(R"({"candidate": {"supersample": 9}})", "explore.candidate.supersample");
  ExpectError(R"({"candidate": {"iterations": "1000"}})", "explore.candidate.iterations");
  ExpectError(R"({"candidate": {"resolution": 9000}})", "explore.candidate.resolution");
  // Too many pixels for one sheet: refused before any allocation.
  ExpectError(R"({"count": 1024, "thumbnail_size": 1024})", "explore.count",
              absl::StatusCode::kResourceExhausted);
  // Other kinds' options do not apply.
  ExpectError("{}", "image", absl::StatusCode::kInvalidArgument, R"(, "image": {"width": 64})");
  ExpectError("{}", "shards", absl::StatusCode::kInvalidArgument, R"(, "shards": 4)");
  ExpectError("{}", "detail", absl::StatusCode::kInvalidArgument,
              R"(, "detail": {"strength": 2})");
}

TEST(ExploreSpec, Defaults) {
  auto plan = Convert("{}");
  ASSERT_TRUE(plan.ok()) << plan.status();
  const ExplorePlan& e = *plan->explore();
  const ExploreParams& p = e.params;
  EXPECT_EQ(p.count, 16);
  EXPECT_EQ(p.draw.dimensions, 2);
  EXPECT_EQ(p.draw.min_maps, 3);
  EXPECT_EQ(p.draw.max_maps, 5);
  EXPECT_EQ(p.draw.coefficient_range, 1);
  EXPECT_EQ(p.measure, ContractionMeasure::kSingularValue);
  EXPECT_EQ(p.threshold, 0.9);
  EXPECT_EQ(p.max_attempts, 160'000u);
  EXPECT_EQ(p.thumbnail_size, 256);
  EXPECT_EQ(p.thumbnail_iterations, uint64_t{1} << 21);
  EXPECT_EQ(p.color.mode, ColorMode::kAddress);
  EXPECT_EQ(p.color.blend, 0.5);
  EXPECT_DOUBLE_EQ(p.look.desaturation, 0.3);
  EXPECT_DOUBLE_EQ(p.look.glow, 0.5);
  EXPECT_DOUBLE_EQ(p.look.glow_radius, 2.56);
  EXPECT_EQ(plan->work.total, 16u);
  EXPECT_EQ(plan->work.unit, "thumbnails");
  auto three = Convert(R"({"dimensions": 3, "measure": "CONTRACTION_MEASURE_DETERMINANT"})");
  ASSERT_TRUE(three.ok()) << three.status();
  EXPECT_EQ(three->explore()->params.draw.coefficient_range, 0.6);
  EXPECT_EQ(three->explore()->params.threshold, 1.5);
  // Admission prices it.
  auto m = server::AdmitMemory(*plan, spec::Limits{}, 2);
  ASSERT_TRUE(m.ok()) << m.status();
  EXPECT_GT(m->estimated_bytes, 16u * 256 * 256 * 12);
}

// The candidate's spec walks exactly the candidate's IFS.
TEST(ExploreSpec, CandidateSpecsConvertToTheExploredIfs) {
  for (const char* body : {R"({"count": 2, "thumbnail_size": 32,
                               "thumbnail_iterations": "65536"})",
                           R"({"count": 2, "thumbnail_size": 32, "dimensions": 3,
                               "measure": "CONTRACTION_MEASURE_DETERMINANT",
                               "thumbnail_iterations": "65536"})",
                           R"({"count": 2, "thumbnail_size": 32, "variations": ["swirl"],
                               "variation_probability": 1,
                               "thumbnail_iterations": "65536"})"}) {
    auto plan = Convert(body);
    ASSERT_TRUE(plan.ok()) << plan.status();
    const ExplorePlan& e = *plan->explore();
    std::vector<ExploreCandidate> kept;
    ASSERT_TRUE(ExploreIfs(e.params, 2, nullptr, [&](const ExploreCandidate& c, RgbImage) {
                  kept.push_back(c);
                  return absl::OkStatus();
                }).ok());
    ASSERT_EQ(kept.size(), 2u);
    for (const ExploreCandidate& c : kept) {
      auto spec = spec::ExploreCandidateSpec(e.candidate_template, c, "cand");
      ASSERT_TRUE(spec.ok()) << spec.status();
      // Through JSON, as the user gets it.
      auto parsed = spec::ParseSpec(spec::SpecToJson(*spec), spec::SpecFormat::kJson);
      ASSERT_TRUE(parsed.ok()) << parsed.status();
      auto cand = spec::ConvertSpec(*parsed, spec::Limits{});
      ASSERT_TRUE(cand.ok()) << cand.status() << "\n" << spec::SpecToJson(*spec);
      const ChaosGamePlan& cg = *cand->chaos_game();
      ASSERT_EQ(cg.params.ifs.maps.size(), c.params.ifs.maps.size());
      for (size_t i = 0; i < c.params.ifs.maps.size(); ++i) {
        EXPECT_EQ(cg.params.ifs.maps[i].pre, c.params.ifs.maps[i].pre);
        EXPECT_EQ(cg.params.ifs.maps[i].variations.size(),
                  c.params.ifs.maps[i].variations.size());
        EXPECT_EQ(cg.params.ifs.probabilities[i], c.params.ifs.probabilities[i]);
      }
      EXPECT_EQ(cg.params.seed, c.params.seed);
      EXPECT_EQ(cg.params.warmup, c.params.warmup);
      EXPECT_EQ(cg.params.color.blend, c.params.color.blend);
      EXPECT_EQ(cand->frame.bounds.min, c.params.frame.bounds.min);
      EXPECT_EQ(cand->frame.bounds.max, c.params.frame.bounds.max);
      ASSERT_TRUE(cg.image.has_value());
      EXPECT_EQ(cg.image->width, 1024);
      EXPECT_FALSE(cg.image->view.camera);
    }
  }
}

TEST(ExploreRunner, WritesTheSheetAndOneSpecPerCandidate) {
  auto plan = Convert(R"({"count": 5, "thumbnail_size": 40, "seed": "3",
                          "thumbnail_iterations": "65536", "columns": 2})");
  ASSERT_TRUE(plan.ok()) << plan.status();
  testing::FakeJobContext ctx;
  ASSERT_TRUE(server::RunJobPlan(*plan, ctx).ok());
  EXPECT_TRUE(ctx.progress_ordered);
  EXPECT_EQ(ctx.Last(server::JobPhase::kIterating).done, 5u);
  EXPECT_EQ(ctx.stats["explore_kept"], 5u);
  EXPECT_GE(ctx.stats["explore_attempts"], 5u);
  auto png = ReadPngPixels(ctx.result());
  ASSERT_TRUE(png.ok()) << png.status();
  const SheetLayout l = ContactSheetLayout(5, 40, 2);
  EXPECT_EQ(png->width, l.width());
  EXPECT_EQ(png->height, l.height());
  for (int i = 1; i <= 5; ++i) {
    const auto file = server::ExtraFilesDir(ctx.result()) / absl::StrFormat("ex.%04d.json", i);
    auto spec = spec::LoadSpecFile(file);
    ASSERT_TRUE(spec.ok()) << spec.status();
    EXPECT_EQ(spec->name(), absl::StrFormat("ex_%04d", i));
    EXPECT_TRUE(spec::ConvertSpec(*spec, spec::Limits{}).ok());
  }
  EXPECT_FALSE(std::filesystem::exists(server::ExtraFilesDir(ctx.result()) / "ex.0006.json"));
}

TEST(ExploreRunner, NothingKeptFailsWithAHint) {
  auto plan = Convert(R"({"count": 3, "threshold": 0.01, "max_attempts": 3,
                          "thumbnail_size": 32})");
  ASSERT_TRUE(plan.ok()) << plan.status();
  testing::FakeJobContext ctx;
  const absl::Status s = server::RunJobPlan(*plan, ctx);
  EXPECT_EQ(s.code(), absl::StatusCode::kFailedPrecondition) << s;
  EXPECT_THAT(std::string(s.message()), HasSubstr("explore.threshold"));
}

}  // namespace
}  // namespace nimbus
