#include "proto/spec_convert.h"
#include "server/memory_admission.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "proto/asset_paths.h"
#include "proto/spec_io.h"
#include "tests/support/test_util.h"

namespace nimbus::spec {
namespace {

using ::testing::HasSubstr;

constexpr char kValid[] = R"({
  "name": "t",
  "grid": {"resolution": [32], "bounds_min": {"x": -1, "y": -1, "z": -1},
           "bounds_max": {"x": 1, "y": 1, "z": 1}},
  "chaos_game": {
    "ifs": {"maps": [
      {"steps": [{"translate": {"x": 0.5}}, {"scale": {"uniform": 0.5}}]},
      {"steps": [{"rotate": {"axis": {"z": 1}, "degrees": 90}}, {"scale": {"xyz": {"x": 0.5, "y": 0.4, "z": 0.3}}}]}
    ]},
    "iterations": "1000"
  }
})";

v1::JobSpec Valid() {
  auto spec = ParseSpec(kValid, SpecFormat::kJson);
  EXPECT_TRUE(spec.ok()) << spec.status();
  return *spec;
}

absl::Status Check(const v1::JobSpec& spec, Limits limits = {}) {
  return ConvertSpec(spec, limits).status();
}

// Conversion, then the server's memory admission, as SubmitJob does.
absl::Status CheckAndAdmit(const v1::JobSpec& spec, Limits limits = {}) {
  auto plan = ConvertSpec(spec, limits);
  if (!plan.ok()) return plan.status();
  return server::AdmitMemory(*plan, limits, 2).status();
}

TEST(SpecConvert, ValidSpecConverts) {
  auto job = ConvertSpec(Valid(), {});
  ASSERT_TRUE(job.ok()) << job.status();
  EXPECT_EQ(job->frame.resolution, (Int3{32, 32, 32}));
  ASSERT_EQ(job->point_run()->ifs.maps.size(), 2u);
  // Determinant mode (no probabilities given): 0.125 vs 0.06.
  EXPECT_NEAR(job->point_run()->ifs.probabilities[0], 0.125 / 0.185, 1e-12);
  EXPECT_EQ(job->point_run()->warmup, 100u);
  EXPECT_NEAR(job->contraction_factors[0], 0.5, 1e-12);
  // Steps compose right to left: scale first, then translate.
  const Vec3 p = job->point_run()->ifs.maps[0].pre.Apply({1, 0, 0});
  EXPECT_NEAR(p.x, 1.0, 1e-12);
}

TEST(SpecConvert, MalformedJsonIsReported) {
  auto spec = ParseSpec("{\"grid\": {\"resolution\": [32,}", SpecFormat::kJson, "bad.json");
  ASSERT_FALSE(spec.ok());
  EXPECT_THAT(std::string(spec.status().message()), HasSubstr("bad.json"));
  EXPECT_THAT(std::string(spec.status().message()), HasSubstr("malformed JSON"));
}

// Random balls inside random balls, `levels` SetSources deep.
std::string NestedTextSpec(int levels) {
  std::string open, close;
  for (int i = 0; i < levels; ++i) open += "random_balls { inside { ", close += "} } ";
  return "set_ifs { maps { condensation { " + open + "sphere { radius: 1 } " + close + "} } }";
}

TEST(SpecConvert, DeeplyNestedTextSpecIsRefusedBeforeTheStackRunsOut) {
  auto deep = ParseSpec(NestedTextSpec(5000), SpecFormat::kText, "deep.txtpb");
  ASSERT_FALSE(deep.ok());
  EXPECT_EQ(deep.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(std::string(deep.status().message()), HasSubstr("deep.txtpb:1:"));
  EXPECT_THAT(std::string(deep.status().message()), HasSubstr("recursion limit of 100"));
  // 3 + 2 * 48 + 1 = 100 message levels is the deepest accepted.
  EXPECT_TRUE(ParseSpec(NestedTextSpec(48), SpecFormat::kText).ok());
  EXPECT_FALSE(ParseSpec(NestedTextSpec(49), SpecFormat::kText).ok());
}

TEST(SpecConvert, GridNameIsAShortPlainNameOfNoOtherGrid) {
  const std::vector<std::pair<std::string, std::string>> bad = {
      {std::string(1 << 20, 'a'), "output.grid_name: must be at most 128 bytes, got 1048576"},
      {std::string("../x\0y", 6), "output.grid_name: use letters, digits"},
      {"a b", "output.grid_name: use letters, digits"},
      {"Cd", "output.grid_name: 'Cd' is the name of another grid"},
      {"counts", "output.grid_name: 'counts' is the name of another grid"},
  };
  for (const auto& [name, message] : bad) {
    v1::JobSpec spec = Valid();
    spec.mutable_output()->set_grid_name(name);
    const absl::Status s = Check(spec);
    EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument) << message;
    EXPECT_THAT(std::string(s.message()), HasSubstr(message));
  }
  v1::JobSpec spec = Valid();
  spec.mutable_output()->set_grid_name(std::string(128, 'd'));
  EXPECT_TRUE(Check(spec).ok());
  spec.mutable_output()->set_grid_name("fog.density-2_b");
  EXPECT_TRUE(Check(spec).ok());
}

TEST(SpecConvert, UnknownStepKindNamesTheField) {
  auto spec = ParseSpec(R"({"chaos_game": {"ifs": {"maps": [{"steps": [{"twist": {}}]}]}}})",
                        SpecFormat::kJson);
  ASSERT_FALSE(spec.ok());
  EXPECT_THAT(std::string(spec.status().message()), HasSubstr("twist"));
}

TEST(SpecConvert, EmptyStepNamesItsPath) {
  v1::JobSpec spec = Valid();
  spec.mutable_chaos_game()->mutable_ifs()->mutable_maps(1)->add_steps();
  const absl::Status s = Check(spec);
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(std::string(s.message()), HasSubstr("chaos_game.ifs.maps[1].steps[2]"));
}

TEST(SpecConvert, ExpandingIfsIsRejectedWithItsFactors) {
  v1::JobSpec spec = Valid();
  auto* step = spec.mutable_chaos_game()->mutable_ifs()->mutable_maps(0)->mutable_steps(1);
  step->mutable_scale()->set_uniform(1.5);
  absl::Status s = Check(spec);
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(std::string(s.message()), HasSubstr("chaos_game.ifs.maps[0] (factor 1.5)"));
  spec.mutable_chaos_game()->mutable_ifs()->set_allow_expanding(true);
  auto job = ConvertSpec(spec, {});
  ASSERT_TRUE(job.ok());
  ASSERT_EQ(job->warnings.size(), 1u);
  EXPECT_THAT(job->warnings[0], HasSubstr("factor 1.5"));
}

TEST(SpecConvert, ResolutionMustBePositive) {
  v1::JobSpec spec = Valid();
  spec.mutable_grid()->clear_resolution();
  for (int v : {64, 0, 64}) spec.mutable_grid()->add_resolution(v);
  absl::Status s = Check(spec);
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(std::string(s.message()), HasSubstr("grid.resolution[1]"));
  spec.mutable_grid()->set_resolution(1, -3);
  EXPECT_THAT(std::string(Check(spec).message()), HasSubstr("got -3"));
}

TEST(SpecConvert, LimitsGiveResourceExhausted) {
  v1::JobSpec spec = Valid();
  spec.mutable_grid()->set_resolution(0, 100000);
  absl::Status s = Check(spec);
  EXPECT_EQ(s.code(), absl::StatusCode::kResourceExhausted);
  EXPECT_THAT(std::string(s.message()), HasSubstr("grid.resolution[0]"));

  spec = Valid();
  spec.mutable_grid()->set_resolution(0, 2048);
  spec.mutable_chaos_game()->set_iterations(uint64_t{1} << 34);
  // This thin attractor touches few tiles (the pilot run sees that), but
  // the tile tables of 2048^3 grids alone take more than 4 MiB.
  Limits tight;
  tight.max_memory_bytes = uint64_t{4} << 20;
  EXPECT_TRUE(Check(spec, tight).ok()) << "ConvertSpec prices no memory";
  s = CheckAndAdmit(spec, tight);
  EXPECT_EQ(s.code(), absl::StatusCode::kResourceExhausted);
  EXPECT_THAT(std::string(s.message()), HasSubstr("memory"));

  spec = Valid();
  spec.mutable_chaos_game()->set_iterations(uint64_t{1} << 50);
  s = Check(spec);
  EXPECT_EQ(s.code(), absl::StatusCode::kResourceExhausted);
  EXPECT_THAT(std::string(s.message()), HasSubstr("chaos_game.iterations"));
}

TEST(SpecConvert, OtherFieldErrors) {
  v1::JobSpec spec = Valid();
  spec.mutable_grid()->mutable_bounds_max()->set_y(-2);
  EXPECT_THAT(std::string(Check(spec).message()), HasSubstr("grid.bounds_max.y"));

  spec = Valid();
  spec.mutable_chaos_game()->set_iterations(0);
  EXPECT_THAT(std::string(Check(spec).message()), HasSubstr("chaos_game.iterations"));

  spec = Valid();
  auto* rot = spec.mutable_chaos_game()->mutable_ifs()->mutable_maps(1)->mutable_steps(0);
  rot->mutable_rotate()->clear_axis();
  EXPECT_THAT(std::string(Check(spec).message()), HasSubstr("maps[1].steps[0].rotate.axis"));

  spec = Valid();
  auto* m = spec.mutable_chaos_game()->mutable_ifs()->mutable_maps(0);
  m->add_steps()->mutable_matrix()->add_values(1);
  EXPECT_THAT(std::string(Check(spec).message()), HasSubstr("maps[0].steps[2].matrix.values"));

  spec = Valid();
  spec.mutable_chaos_game()->mutable_ifs()->mutable_maps(0)->add_variations()->set_name("wobble");
  EXPECT_THAT(std::string(Check(spec).message()), HasSubstr("unknown variation 'wobble'"));

  spec = Valid();
  spec.clear_chaos_game();
  EXPECT_THAT(std::string(Check(spec).message()), HasSubstr("generator"));
}

TEST(SpecConvert, ExplicitProbabilitiesAreNormalised) {
  v1::JobSpec spec = Valid();
  spec.mutable_chaos_game()->mutable_ifs()->mutable_maps(0)->set_probability(3);
  spec.mutable_chaos_game()->mutable_ifs()->mutable_maps(1)->set_probability(1);
  auto job = ConvertSpec(spec, {});
  ASSERT_TRUE(job.ok());
  EXPECT_DOUBLE_EQ(job->point_run()->ifs.probabilities[0], 0.75);
  spec.mutable_chaos_game()->mutable_ifs()->mutable_maps(1)->set_probability(-1);
  EXPECT_THAT(std::string(Check(spec).message()), HasSubstr("maps[1].probability"));
}

TEST(SpecConvert, TextFormatAndJsonAgree) {
  auto text = LoadSpecFile(testing::SourcePath("examples/sierpinski_tetrahedron.txtpb"));
  ASSERT_TRUE(text.ok()) << text.status();
  auto json = LoadSpecFile(testing::SourcePath("examples/sierpinski_tetrahedron.json"));
  ASSERT_TRUE(json.ok()) << json.status();
  auto a = ConvertSpec(*text, {}), b = ConvertSpec(*json, {});
  ASSERT_TRUE(a.ok() && b.ok());
  for (int i = 0; i < 4; ++i)
    EXPECT_EQ(a->point_run()->ifs.maps[i].pre, b->point_run()->ifs.maps[i].pre);
  auto bad = ParseSpec("grid { resolution: [1, }", SpecFormat::kText, "x.txtpb");
  ASSERT_FALSE(bad.ok());
  EXPECT_THAT(std::string(bad.status().message()), HasSubstr("x.txtpb:1:"));
}

TEST(SpecConvert, EveryExampleValidates) {
  for (const auto& entry : std::filesystem::directory_iterator(testing::SourcePath("examples"))) {
    const auto ext = entry.path().extension();
    if (ext != ".json" && ext != ".txtpb") continue;
    auto spec = LoadSpecFile(entry.path());
    ASSERT_TRUE(spec.ok()) << entry.path() << ": " << spec.status();
    // Asset paths are relative to the spec file, as the CLI reads them.
    ResolveAssetPaths(*spec, entry.path().parent_path());
    EXPECT_TRUE(CheckAndAdmit(*spec).ok()) << entry.path() << ": " << CheckAndAdmit(*spec);
  }
}

TEST(SpecConvert, HashIsStableAndSensitive) {
  v1::JobSpec a = Valid(), b = Valid();
  EXPECT_EQ(SpecHash(a), SpecHash(b));
  b.mutable_chaos_game()->set_seed(9);
  EXPECT_NE(SpecHash(a), SpecHash(b));
}

}  // namespace
}  // namespace nimbus::spec
