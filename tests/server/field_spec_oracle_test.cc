// Fractal-field specs reach the plan as the spec says (docs/fractal_fields.md):
// mesh weights equal A · ratio^(H·k) for the power rule and ratio^(n·k)
// for the cell-volume rule, worked from the spec's numbers; and a field
// with a linear wind equals the same spec without wind displaced by v·t at
// a time that is no whole period.
#include <gtest/gtest.h>

#include <cmath>
#include <string>

#include "core/field/fractal_field.h"
#include "proto/spec_convert.h"
#include "proto/spec_io.h"

namespace nimbus::spec {
namespace {

// A 3D field of `count` meshes from cell 1 by `ratio`, `weights` as JSON.
v1::JobSpec FieldSpec(const std::string& weights, const std::string& mapping = "{}",
                      double ratio = 0.5, int count = 5) {
  auto spec = ParseSpec(R"({"name": "f", "grid": {"resolution": [8]},
    "fractal_field": {"field": {"dimensions": 3, "seed": "4",
      "mesh_series": {"base_cell_size": [1], "ratio": )" +
                            std::to_string(ratio) + R"(, "count": )" + std::to_string(count) +
                            R"(},
      "weights": )" + weights + R"(, "mapping": )" + mapping + "}}}",
                        SpecFormat::kJson);
  EXPECT_TRUE(spec.ok()) << spec.status();
  return spec.ok() ? *spec : v1::JobSpec();
}

std::vector<double> PlanWeights(const v1::JobSpec& spec) {
  auto job = ConvertSpec(spec, {});
  EXPECT_TRUE(job.ok()) << job.status();
  std::vector<double> w;
  if (!job.ok() || job->fractal_field() == nullptr) return w;
  for (const FieldMesh& m : job->fractal_field()->field.meshes) w.push_back(m.weight);
  return w;
}

TEST(FieldSpecOracle, PowerRuleWeightsAreAmplitudeTimesRatioToTheHurstK) {
  struct Case {
    double hurst, amplitude, ratio;
  };
  for (const Case c : {Case{0.8, 1, 0.5}, Case{0.3, 2.5, 0.5}, Case{1.6, 1, 0.25}}) {
    const std::string weights = R"({"rule": "WEIGHT_RULE_POWER", "hurst": )" +
                                std::to_string(c.hurst) + R"(, "amplitude": )" +
                                std::to_string(c.amplitude) + "}";
    const std::vector<double> w = PlanWeights(FieldSpec(weights, "{}", c.ratio, 5));
    ASSERT_EQ(w.size(), 5u);
    for (int k = 0; k < 5; ++k)
      EXPECT_NEAR(w[size_t(k)], c.amplitude * std::pow(c.ratio, c.hurst * k), 1e-12)
          << "H " << c.hurst << " mesh " << k;
  }
  // H = 0.8, ratio 1/2: mesh 2's weight 0.5^1.6 = 0.329876977693...
  const std::vector<double> w =
      PlanWeights(FieldSpec(R"({"rule": "WEIGHT_RULE_POWER", "hurst": 0.8})"));
  ASSERT_EQ(w.size(), 5u);
  EXPECT_NEAR(w[2], 0.32987697769322355, 1e-12);
}

TEST(FieldSpecOracle, CellVolumeRuleWeightsAreTheVolumeRatio) {
  // Three axes, cells halving: volume ratio 1/8 per mesh.
  const std::vector<double> w = PlanWeights(FieldSpec(R"({"rule": "WEIGHT_RULE_CELL_VOLUME"})"));
  ASSERT_EQ(w.size(), 5u);
  for (int k = 0; k < 5; ++k) EXPECT_NEAR(w[size_t(k)], std::pow(0.125, k), 1e-15) << k;
}

TEST(FieldSpecOracle, ConvertedWindIsTheStillFieldDisplacedByVelocityTimesTime) {
  const std::string weights = R"({"rule": "WEIGHT_RULE_POWER", "hurst": 0.5})";
  auto windy = ConvertSpec(
      FieldSpec(weights, R"({"wind": {"kind": "WIND_KIND_LINEAR", "velocity": [0.3, -0.2, 0.1]}})"),
      {});
  auto still = ConvertSpec(FieldSpec(weights), {});
  ASSERT_TRUE(windy.ok() && still.ok()) << windy.status() << still.status();
  const FractalField a(windy->fractal_field()->field), b(still->fractal_field()->field);
  int differs = 0;
  for (double t : {0.37, 2.9})
    for (double s = -1; s < 1; s += 0.23) {
      const double x[3] = {s, 0.4 - s, 0.8 * s};
      const double moved[3] = {x[0] + 0.3 * t, x[1] - 0.2 * t, x[2] + 0.1 * t};
      EXPECT_NEAR(a.Sample(x, t), b.Sample(moved, t), 1e-12) << "t " << t << " at " << s;
      differs += std::abs(a.Sample(x, t) - b.Sample(x, t)) > 1e-3;
    }
  EXPECT_GT(differs, 10);
}

}  // namespace
}  // namespace nimbus::spec
