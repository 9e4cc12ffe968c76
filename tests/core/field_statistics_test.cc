// The field's statistics follow its weights: mean 0 and the variance
// Σ p_k² (1/3)(2/3)^n for n-linear meshes; and the radially averaged power
// spectrum of a 2D field falls with the slope -(2H + 2) that the weight rule
// p_k = (c_k / c_0)^H implies (tests/support/field_oracles.h).
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "core/field/field_grid.h"
#include "core/field/field_recipe.h"
#include "tests/support/field_oracles.h"

namespace nimbus {
namespace {

std::vector<float> Grid2D(const FractalField& f, int n) {
  FieldGrid g;
  g.count = {n, n, 1};
  std::vector<float> out(g.size());
  EXPECT_TRUE(EvaluateFieldGrid(f, g, out.data()).ok());
  return out;
}

TEST(FieldStatistics, MeanAndVarianceMatchTheWeights) {
  FractalFieldParams p;
  p.dims = 2;
  p.mapping.space_dims = 2;
  p.seed = 2024;
  const double cells[] = {23.3, 11.7, 5.9, 3.1};
  const std::vector<double> weights = {1, 0.5, 0.25, 0.125};
  for (size_t k = 0; k < 4; ++k) {
    FieldMesh m;
    m.cell = {cells[k], cells[k], 1, 1};
    m.offset = {0.37 * double(k), 0.71 * double(k), 0, 0};
    p.meshes.push_back(m);
  }
  ASSERT_TRUE(ApplyWeightRule(WeightRule::kExplicit, 1, 0, weights, 2, p.meshes).ok());
  FractalField f(p);
  const int n = 1024;
  const auto v = Grid2D(f, n);
  double sum = 0, sum2 = 0;
  for (float x : v) {
    sum += x;
    sum2 += double(x) * x;
  }
  const double mean = sum / double(v.size()), var = sum2 / double(v.size()) - mean * mean;
  const double expected = testing::LinearFieldVariance(weights, 2);
  // The coarsest mesh has ~1900 independent nodes on this grid: its mean
  // and variance are known to a few percent.
  EXPECT_NEAR(mean, 0, 4 * std::sqrt(1.0 / 3 / (n / cells[0]) / (n / cells[0])));
  EXPECT_NEAR(var / expected, 1.0, 0.10) << "variance " << var << " expected " << expected;
}

TEST(FieldStatistics, WeightRules) {
  MeshSeries s;
  s.base_cell = {8, 4, 2, 1};
  s.ratio = 0.5;
  s.count = 4;
  auto meshes = ExpandMeshSeries(s, 3);
  ASSERT_TRUE(ApplyWeightRule(WeightRule::kCellVolume, 2, 0, {}, 3, meshes).ok());
  for (size_t k = 0; k < 4; ++k) EXPECT_NEAR(meshes[k].weight, 2 * std::pow(0.125, double(k)), 1e-12);
  ASSERT_TRUE(ApplyWeightRule(WeightRule::kPower, 1, 0.5, {}, 3, meshes).ok());
  for (size_t k = 0; k < 4; ++k) EXPECT_NEAR(meshes[k].weight, std::pow(0.5, 0.5 * double(k)), 1e-12);
  EXPECT_FALSE(ApplyWeightRule(WeightRule::kExplicit, 1, 0, {1, 2}, 3, meshes).ok());
  EXPECT_FALSE(ApplyWeightRule(WeightRule::kExplicit, 1, 0, {1, 2, NAN, 4}, 3, meshes).ok());
}

double SpectrumSlope(double hurst, FieldInterpolation interp) {
  // Cells 64 .. 2 samples.
  FractalField f(testing::SeriesParams(2, 2, interp, {64, 64, 1, 1}, 6, hurst, 31));
  const int n = 512;
  const auto v = Grid2D(f, n);
  const std::vector<double> image(v.begin(), v.end());
  const auto power = testing::RadialPowerSpectrum(image, n);
  // Wavelengths 64 down to 4 samples: inside the meshes' range, clear of
  // the finest mesh's cut-off.
  return testing::LogLogSlope(power, 8, 128);
}

TEST(FieldStatistics, PowerSpectrumFollowsTheWeightRule) {
  // Tolerance ±0.4 on the slope: six discrete octaves make the spectrum
  // scalloped, and 512² samples leave some noise in each bin.
  for (double hurst : {0.3, 0.5, 0.8}) {
    const double slope = SpectrumSlope(hurst, FieldInterpolation::kLinear);
    EXPECT_NEAR(slope, -(2 * hurst + 2), 0.4) << "H = " << hurst;
  }
}

}  // namespace
}  // namespace nimbus
