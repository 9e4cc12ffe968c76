// The node hash RDN and the grid evaluator's determinism: the same spec and
// seed give the same values whatever the thread count or slab partition.
#include <gtest/gtest.h>
#include <tbb/task_arena.h>

#include <cmath>
#include <cstring>
#include <vector>

#include "core/field/field_grid.h"
#include "core/field/field_recipe.h"
#include "core/field/node_hash.h"
#include "tests/support/field_oracles.h"

namespace nimbus {
namespace {

FractalFieldParams Params(int dims, int space, FieldInterpolation interp, int meshes) {
  return testing::SeriesParams(dims, space, interp, {8, 8, 8, 8}, meshes, 0.7, 1234);
}

std::vector<float> Evaluate(const FractalField& f, const FieldGrid& g, int threads) {
  std::vector<float> out(g.size());
  tbb::task_arena arena(threads);
  arena.execute([&] { EXPECT_TRUE(EvaluateFieldGrid(f, g, out.data()).ok()); });
  return out;
}

TEST(NodeHash, IsHashCoordsOfSeedMeshAndNode) {
  // RDN is part of the file format: the values of every stored result
  // depend on it, so it is pinned to core/base/random.h's HashCoords.
  const NodeSlots a{0, 0, 0, 0}, b{1, -2, 3, -4};
  EXPECT_EQ(NodeValue(0, 0, a), HashToValue(HashCoords(0, 0, 0, 0, 0, 0)));
  EXPECT_EQ(NodeValue(7, 3, b),
            HashToValue(HashCoords(7, 3, 1, uint64_t(-2), 3, uint64_t(-4))));
  EXPECT_NE(NodeValue(0, 0, a), NodeValue(0, 0, b));
  EXPECT_NE(NodeValue(0, 1, a), NodeValue(0, 0, a));  // mesh rank matters
  EXPECT_NE(NodeValue(1, 0, a), NodeValue(0, 0, a));  // seed matters
  EXPECT_EQ(HashToValue(0), -1.0f);
  EXPECT_EQ(HashToValue(~uint64_t{0}), 1.0f - 0x1p-23f);
  // The grid evaluator's chain, one coordinate at a time, is the same hash.
  const uint64_t chained =
      Mix64(Mix64(Mix64(Mix64(MeshPrefix(7, 3) ^ 1) ^ uint64_t(-2)) ^ 3) ^ uint64_t(-4));
  EXPECT_EQ(chained, HashCoords(7, 3, 1, uint64_t(-2), 3, uint64_t(-4)));
}

TEST(NodeHash, FieldAxesMapToSlots) {
  // A terrain with time (x, y, t): time takes the last slot, z stays 0.
  FractalFieldParams p = Params(3, 2, FieldInterpolation::kLinear, 1);
  FractalField f(p);
  const int64_t node[3] = {5, -6, 7};
  EXPECT_EQ(f.Node(0, node), NodeValue(p.seed, 0, {5, -6, 0, 7}));
}

TEST(NodeHash, UniformMoments) {
  double sum = 0, sum2 = 0;
  int n = 0;
  float lo = 1, hi = -1;
  for (int64_t x = -100; x < 100; ++x)
    for (int64_t y = -100; y < 100; ++y) {
      const double v = NodeValue(99, 3, {x, y, 0, 0});
      lo = std::min(lo, float(v));
      hi = std::max(hi, float(v));
      sum += v;
      sum2 += v * v;
      ++n;
    }
  EXPECT_GE(lo, -1.0f);
  EXPECT_LT(hi, 1.0f);
  const double mean = sum / n, var = sum2 / n - mean * mean;
  // Uniform on [-1, 1): mean 0, variance 1/3; 40000 samples.
  EXPECT_NEAR(mean, 0.0, 4 * std::sqrt(1.0 / 3 / n));
  EXPECT_NEAR(var, 1.0 / 3, 0.01);
}

TEST(FieldGrid, ThreadCountIndependentBytes) {
  for (auto interp : {FieldInterpolation::kLinear, FieldInterpolation::kPseudoCubic,
                      FieldInterpolation::kQuintic}) {
    for (int dims : {3, 4}) {
      FractalField f(Params(dims, 3, interp, 5));
      FieldGrid g;
      g.count = {37, 29, 41};
      g.origin = {-3.3, 1.7, 0.25};
      g.step = {0.61, 0.73, 0.55};
      g.time = 2.5;
      const auto one = Evaluate(f, g, 1);
      const auto two = Evaluate(f, g, 2);
      ASSERT_EQ(one.size(), two.size());
      EXPECT_EQ(0, std::memcmp(one.data(), two.data(), one.size() * sizeof(float)))
          << "dims " << dims << " interpolation " << int(interp);
    }
  }
}

TEST(FieldGrid, SubGridsGiveTheSameSamples) {
  // A sample's value depends only on its position, not on the grid around
  // it: a grid that starts 5 samples later holds the same values.
  FractalField f(Params(3, 3, FieldInterpolation::kPseudoCubic, 4));
  FieldGrid g;
  g.count = {20, 16, 24};
  g.step = {0.5, 0.5, 0.5};
  const auto whole = Evaluate(f, g, 2);
  FieldGrid sub = g;
  sub.count = {15, 16, 24};
  sub.origin[0] = 5 * 0.5;
  const auto part = Evaluate(f, sub, 2);
  for (size_t i = 0; i < part.size(); ++i)
    ASSERT_NEAR(part[i], whole[i + size_t(5) * 16 * 24], 1e-6f) << i;
}

}  // namespace
}  // namespace nimbus
