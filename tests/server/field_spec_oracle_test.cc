// Fractal-field specs reach the plan and the files as the spec says
// (docs/fractal_fields.md): mesh weights equal A · ratio^(H·k) for the
// power rule and ratio^(n·k) for the cell-volume rule, worked from the
// spec's numbers; a field with a linear wind equals the same spec without
// wind displaced by v·t at a time that is no whole period, and a sine wind
// by A·sin(2πt/P + φ) with φ given in degrees; a periodic axis holds a
// whole number of each mesh's cells, rounded; the written
// density is the documented gain, threshold and clip of v = field / Σ|p|
// at each voxel centre, and the height PNG holds (v + 1)/2 · 65535 with
// north at the top, both from the point evaluator.
#include <gtest/gtest.h>

#include <cmath>
#include <memory>
#include <optional>
#include <string>

#include "core/field/fractal_field.h"
#include "core/io/image_io.h"
#include "core/io/vdb_io.h"
#include "proto/spec_convert.h"
#include "proto/spec_io.h"
#include "server/job_runner.h"
#include "server/result_store.h"
#include "tests/support/fake_job_context.h"

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

// A spec's plan and its run through the runner; the files stay in the
// context's folder. `job` is empty when the spec does not convert.
struct FieldRun {
  std::optional<JobPlan> job;
  std::unique_ptr<nimbus::testing::FakeJobContext> ctx =
      std::make_unique<nimbus::testing::FakeJobContext>();
};

FieldRun RunField(const std::string& json) {
  FieldRun run;
  auto spec = ParseSpec(json, SpecFormat::kJson);
  EXPECT_TRUE(spec.ok()) << spec.status();
  auto job = spec.ok() ? ConvertSpec(*spec, {}) : absl::StatusOr<JobPlan>(spec.status());
  EXPECT_TRUE(job.ok()) << job.status();
  if (!job.ok()) return run;
  run.job = *std::move(job);
  EXPECT_TRUE(server::RunJobPlan(*run.job, *run.ctx).ok());
  return run;
}

// y = gain · (v - threshold); 0 for y <= 0, else min(y, 1), or 1 - e^-y
// with soft_clip.
TEST(FieldSpecOracle, WrittenDensityIsGainThresholdAndClipOfTheNormalisedField) {
  for (const bool soft : {false, true}) {
    SCOPED_TRACE(soft ? "soft clip" : "hard clip");
    const FieldRun run = RunField(std::string(R"({"name": "fog", "grid": {"resolution": [10, 9, 8]},
      "fractal_field": {"field": {"dimensions": 3, "seed": "8",
        "mesh_series": {"base_cell_size": [0.6], "count": 3}},
        "density": {"threshold": -0.1, "gain": 3, "soft_clip": )") +
                                  (soft ? "true" : "false") + "}}}");
    ASSERT_TRUE(run.job.has_value());
    const FractalField f(run.job->fractal_field()->field);
    auto vol = ReadVdbFile(run.ctx->result());
    ASSERT_TRUE(vol.ok()) << vol.status();
    const GridFrame& g = run.job->frame;
    ASSERT_EQ(vol->frame.resolution, g.resolution);
    int clipped = 0, zero = 0;
    for (int x = 0; x < 10; ++x)
      for (int y = 0; y < 9; ++y)
        for (int z = 0; z < 8; ++z) {
          const Vec3 c = g.VoxelCenter({x, y, z});
          const double p[3] = {c.x, c.y, c.z};
          const double u = 3 * (f.Sample(p, 0) / f.WeightSum() + 0.1);
          const double want = u <= 0 ? 0 : soft ? 1 - std::exp(-u) : std::min(u, 1.0);
          clipped += u > 1;
          zero += u <= 0;
          ASSERT_NEAR(vol->At(x, y, z), want, 1e-5) << x << "," << y << "," << z;
        }
    EXPECT_GT(clipped, 10);  // both sides of the clip are exercised
    EXPECT_GT(zero, 10);
  }
}

TEST(FieldSpecOracle, HeightPngIsTheNormalisedFieldNorthUp) {
  const FieldRun run = RunField(R"({"name": "hills", "grid": {"resolution": [12, 7, 8]},
    "fractal_field": {"field": {"dimensions": 2, "seed": "3",
      "mesh_series": {"base_cell_size": [0.8], "count": 3}}, "terrain": {}}})");
  ASSERT_TRUE(run.job.has_value());
  const FractalField f(run.job->fractal_field()->field);
  auto png = ReadPngPixels(server::ExtraFilesDir(run.ctx->result()) / "hills.height.png");
  ASSERT_TRUE(png.ok()) << png.status();
  ASSERT_EQ(png->width, 12);
  ASSERT_EQ(png->height, 7);
  ASSERT_EQ(png->channels, 1);
  for (int x = 0; x < 12; ++x)
    for (int y = 0; y < 7; ++y) {
      const Vec3 c = run.job->frame.VoxelCenter({x, y, 0});
      const double p[2] = {c.x, c.y};
      const double v = f.Sample(p, 0) / f.WeightSum();
      const int row = 6 - y;  // the largest y (north) is the top row
      EXPECT_NEAR(png->samples[size_t(row) * 12 + size_t(x)], (v + 1) / 2 * 65535, 1.01)
          << x << "," << y;
    }
}

// A sine wind given in degrees: δ(t) = A·sin(2π t / P + φ). At t = 0.3
// with P = 1.2 and φ = 30°, the angle is 90° + 30°, so δ = A·√3/2.
TEST(FieldSpecOracle, ConvertedSineWindIsTheStillFieldDisplacedByItsPhase) {
  const std::string weights = R"({"rule": "WEIGHT_RULE_POWER", "hurst": 0.5})";
  auto windy = ConvertSpec(FieldSpec(weights, R"({"wind": {"kind": "WIND_KIND_SINE",
      "amplitude": [0.4, 0, -0.2], "period": 1.2, "phase_degrees": 30}})"),
                           {});
  auto still = ConvertSpec(FieldSpec(weights), {});
  ASSERT_TRUE(windy.ok() && still.ok()) << windy.status() << still.status();
  const FractalField a(windy->fractal_field()->field), b(still->fractal_field()->field);
  const double s = std::sqrt(3) / 2;
  for (double q = -1; q < 1; q += 0.23) {
    const double x[3] = {q, 0.4 - q, 0.8 * q};
    const double moved[3] = {x[0] + 0.4 * s, x[1], x[2] - 0.2 * s};
    EXPECT_NEAR(a.Sample(x, 0.3), b.Sample(moved, 0.3), 1e-12) << q;
  }
}

// A periodic axis holds a whole number of cells of every mesh: period 2
// over cells 0.3 · 0.5^k gives round(2 / cell) = 7, 13, 27 nodes and cells
// 2/7, 2/13, 2/27; the axes without a period keep their cells.
TEST(FieldSpecOracle, PeriodicAxisSnapsCellsToAWholeNumberPerPeriod) {
  auto spec = ParseSpec(R"({"name": "p", "grid": {"resolution": [8]},
    "fractal_field": {"field": {"dimensions": 3, "seed": "1",
      "mesh_series": {"base_cell_size": [0.3], "count": 3, "aligned": true},
      "mapping": {"period": [2]}}}})",
                        SpecFormat::kJson);
  ASSERT_TRUE(spec.ok()) << spec.status();
  auto job = ConvertSpec(*spec, {});
  ASSERT_TRUE(job.ok()) << job.status();
  const auto& meshes = job->fractal_field()->field.meshes;
  ASSERT_EQ(meshes.size(), 3u);
  const int64_t nodes[3] = {7, 13, 27};
  for (size_t k = 0; k < 3; ++k) {
    EXPECT_EQ(meshes[k].period_nodes[0], nodes[k]) << k;
    EXPECT_DOUBLE_EQ(meshes[k].cell[0], 2.0 / double(nodes[k])) << k;
    EXPECT_EQ(meshes[k].period_nodes[1], 0) << k;
    EXPECT_DOUBLE_EQ(meshes[k].cell[1], 0.3 * std::pow(0.5, double(k))) << k;
  }
  // And the field repeats: x and x + 2 give the same value.
  const FractalField f(job->fractal_field()->field);
  for (double q = -0.9; q < 1; q += 0.31) {
    const double x[3] = {q, 0.2, -0.4}, shifted[3] = {q + 2, 0.2, -0.4};
    EXPECT_NEAR(f.Sample(x, 0), f.Sample(shifted, 0), 1e-12) << q;
  }
}

}  // namespace
}  // namespace nimbus::spec
