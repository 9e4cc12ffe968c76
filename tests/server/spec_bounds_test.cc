// Hostile numbers in a spec are refused at submit by field name: unknown
// enum values, non-finite or absurd magnitudes, and warm-up beyond the
// iteration budget.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <limits>

#include "proto/spec_convert.h"
#include "proto/spec_io.h"

namespace nimbus::spec {
namespace {

using ::testing::HasSubstr;

constexpr char kValid[] = R"({
  "name": "t",
  "grid": {"resolution": [16], "bounds_min": {"x": -1, "y": -1, "z": -1},
           "bounds_max": {"x": 1, "y": 1, "z": 1}},
  "chaos_game": {
    "ifs": {"maps": [
      {"steps": [{"translate": {"x": 0.5}}, {"scale": {"uniform": 0.5}}], "probability": 1},
      {"steps": [{"scale": {"uniform": 0.5}}], "probability": 1}
    ]},
    "iterations": "1000"
  }
})";

v1::JobSpec Valid() {
  auto spec = ParseSpec(kValid, SpecFormat::kJson);
  EXPECT_TRUE(spec.ok()) << spec.status();
  return *spec;
}

// Expects INVALID_ARGUMENT (or `code`) whose message starts with `field`.
void ExpectRefused(const v1::JobSpec& spec, const std::string& field,
                   absl::StatusCode code = absl::StatusCode::kInvalidArgument,
                   Limits limits = {}) {
  const absl::Status st = ConvertSpec(spec, limits).status();
  EXPECT_EQ(st.code(), code) << st;
  EXPECT_THAT(std::string(st.message()), ::testing::StartsWith(field + ":")) << st;
}

TEST(SpecBounds, ValidSpecStillConverts) { EXPECT_TRUE(ConvertSpec(Valid(), {}).ok()); }

TEST(SpecBounds, UnknownEnumNumbersAreRefusedByName) {
  auto spec = Valid();
  spec.mutable_chaos_game()->mutable_ifs()->set_probability_mode(v1::ProbabilityMode(99));
  ExpectRefused(spec, "chaos_game.ifs.probability_mode");

  spec = Valid();
  spec.mutable_output()->set_density_mapping(v1::DensityMapping(99));
  ExpectRefused(spec, "output.density_mapping");

  spec = Valid();
  spec.mutable_chaos_game()->set_raw_counts(v1::RawCounts(99));
  ExpectRefused(spec, "chaos_game.raw_counts");

  spec = Valid();
  spec.mutable_chaos_game()->mutable_color()->set_mode(v1::ColorMode(99));
  ExpectRefused(spec, "chaos_game.color.mode");
}

TEST(SpecBounds, AbsurdMagnitudesAreRefusedByName) {
  const double inf = std::numeric_limits<double>::infinity();
  auto spec = Valid();
  spec.mutable_grid()->mutable_bounds_max()->set_y(1e308);
  ExpectRefused(spec, "grid.bounds_max.y");

  spec = Valid();
  spec.mutable_grid()->mutable_bounds_min()->set_x(-1e13);
  ExpectRefused(spec, "grid.bounds_min.x");

  spec = Valid();
  spec.mutable_chaos_game()->mutable_ifs()->mutable_maps(1)->set_probability(1e308);
  ExpectRefused(spec, "chaos_game.ifs.maps[1].probability");

  spec = Valid();
  spec.mutable_chaos_game()->mutable_ifs()->mutable_maps(0)->mutable_steps(0)
      ->mutable_translate()->set_x(2e12);
  ExpectRefused(spec, "chaos_game.ifs.maps[0].steps[0].translate");

  spec = Valid();
  auto* m = spec.mutable_chaos_game()->mutable_ifs()->mutable_maps(1)->add_steps()
                ->mutable_matrix();
  for (int i = 0; i < 12; ++i) m->add_values(i == 5 ? -1e300 : 0.1);
  ExpectRefused(spec, "chaos_game.ifs.maps[1].steps[1].matrix.values[5]");

  spec = Valid();
  spec.mutable_chaos_game()->mutable_ifs()->mutable_maps(0)->mutable_steps(1)
      ->mutable_scale()->set_uniform(inf);
  ExpectRefused(spec, "chaos_game.ifs.maps[0].steps[1].scale.uniform");

  spec = Valid();
  auto* v = spec.mutable_chaos_game()->mutable_ifs()->mutable_maps(0)->add_variations();
  v->set_name("sinusoidal");
  v->set_weight(1e200);
  ExpectRefused(spec, "chaos_game.ifs.maps[0].variations[0].weight");

  spec = Valid();
  spec.mutable_output()->set_density_mapping(v1::DENSITY_MAPPING_GAMMA);
  spec.mutable_output()->set_gamma(1e9);
  ExpectRefused(spec, "output.gamma");
}

TEST(SpecBounds, LargestAllowedMagnitudesPass) {
  auto spec = Valid();
  spec.mutable_grid()->mutable_bounds_min()->set_x(-1e12);
  spec.mutable_grid()->mutable_bounds_max()->set_x(1e12);
  spec.mutable_chaos_game()->mutable_ifs()->mutable_maps(1)->set_probability(1e12);
  EXPECT_TRUE(ConvertSpec(spec, {}).ok()) << ConvertSpec(spec, {}).status();
}

TEST(SpecBounds, WarmupHasACapAndCountsTowardTheIterationLimit) {
  auto spec = Valid();
  spec.mutable_chaos_game()->set_warmup(4294967295u);
  ExpectRefused(spec, "chaos_game.warmup");

  // 1000 iterations are one chunk of 16 walkers: 1000 + 16 × warmup steps.
  spec = Valid();
  spec.mutable_chaos_game()->set_warmup(1000);
  Limits limits;
  limits.max_iterations = 1000 + 16 * 1000;
  EXPECT_TRUE(ConvertSpec(spec, limits).ok());
  limits.max_iterations = 1000 + 16 * 1000 - 1;
  ExpectRefused(spec, "chaos_game.warmup", absl::StatusCode::kResourceExhausted, limits);

  // The default warm-up (100) counts too.
  spec = Valid();
  limits.max_iterations = 1000;
  ExpectRefused(spec, "chaos_game.warmup", absl::StatusCode::kResourceExhausted, limits);
}

// A palette at its bound converts; one stop more, a list past the general
// bound, or an unknown field deep inside is refused by field before the
// converter reads anything.
TEST(SpecBounds, ListsAndUnknownFieldsAreBoundedByField) {
  auto spec = Valid();
  auto* palette = spec.mutable_chaos_game()->mutable_color()->mutable_palette();
  for (int i = 0; i < 4096; ++i) {
    auto* stop = palette->add_stops();
    stop->set_position(i / 4095.0);
    stop->mutable_rgb()->set_x(0.5);
  }
  const auto message = [](const v1::JobSpec& s) {
    return std::string(ConvertSpec(s, {}).status().message());
  };
  EXPECT_TRUE(ConvertSpec(spec, {}).ok()) << ConvertSpec(spec, {}).status();
  palette->add_stops()->set_position(1);
  EXPECT_EQ(message(spec),
            "chaos_game.color.palette.stops: must have at most 4096 entries, got 4097");

  spec = Valid();
  auto* jelly = spec.mutable_jelly();
  for (int i = 0; i < 65'537; ++i) jelly->add_start_points();
  EXPECT_EQ(message(spec), "jelly.start_points: must have at most 65536 entries, got 65537");

  spec = Valid();
  auto* step = spec.mutable_chaos_game()->mutable_ifs()->mutable_maps(0)->mutable_steps(1);
  step->GetReflection()->MutableUnknownFields(step)->AddFixed32(4242, 7);
  EXPECT_THAT(message(spec),
              ::testing::StartsWith("chaos_game.ifs.maps[0].steps[1]: has a field "
                                    "this server does not know (field number 4242)"));
}

}  // namespace
}  // namespace nimbus::spec
