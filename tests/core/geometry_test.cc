#include "core/base/geometry.h"

#include <gtest/gtest.h>

#include "core/chaos/point_map.h"

namespace nimbus {
namespace {

TEST(Affine3, ComposesRightToLeft) {
  // T(0,1,0) after Rx(90) after H(0.5) sends (0,1,0) to (0,1,0.5).
  const Affine3 f = Affine3::Translate({0, 1, 0}) * Affine3::Rotate({1, 0, 0}, 90) *
                    Affine3::Scale({0.5, 0.5, 0.5});
  const Vec3 p = f.Apply({0, 1, 0});
  EXPECT_NEAR(p.x, 0, 1e-12);
  EXPECT_NEAR(p.y, 1, 1e-12);
  EXPECT_NEAR(p.z, 0.5, 1e-12);
}

TEST(Affine3, DeterminantAndContraction) {
  const Affine3 s = Affine3::Scale({0.5, 0.25, 2});
  EXPECT_DOUBLE_EQ(s.Determinant(), 0.25);
  EXPECT_NEAR(s.ContractionFactor(), 2.0, 1e-12);
  const Affine3 r = Affine3::Rotate({1, 2, 3}, 37) * Affine3::Scale({0.5, 0.5, 0.5});
  EXPECT_NEAR(r.ContractionFactor(), 0.5, 1e-9);
  EXPECT_NEAR(r.Determinant(), 0.125, 1e-12);
  EXPECT_NEAR(s.SmallestSingularValue(), 0.25, 1e-12);
  EXPECT_NEAR(r.SmallestSingularValue(), 0.5, 1e-9);
  // A shear stretches more than its diagonal suggests, and shrinks as much.
  EXPECT_LT(Affine3::Shear(1, 0, 0, 0, 0, 0).SmallestSingularValue(), 0.62);
  EXPECT_GT(Affine3::Shear(1, 0, 0, 0, 0, 0).ContractionFactor(), 1.6);
}

TEST(AliasTable, SamplesInProportion) {
  AliasTable table({0.30, 0.20, 0.25, 0.25});
  Rng rng(1, 0);
  std::vector<int> counts(4);
  const int n = 400000;
  for (int i = 0; i < n; ++i) counts[table.Sample(rng.Next())]++;
  EXPECT_NEAR(counts[0] / double(n), 0.30, 0.004);
  EXPECT_NEAR(counts[1] / double(n), 0.20, 0.004);
  EXPECT_NEAR(counts[2] / double(n), 0.25, 0.004);
}

TEST(DeterminantProbabilities, FloorKeepsDegenerateMaps) {
  std::vector<PointMap> maps(2);
  maps[0].pre = Affine3::Scale({0.5, 0.5, 0.5});
  maps[1].pre = Affine3::Scale({0.5, 0.5, 0});
  const auto p = DeterminantProbabilities(maps, 0.01);
  EXPECT_GT(p[1], 0);
  EXPECT_NEAR(p[0] + p[1], 1.0, 1e-15);
  EXPECT_NEAR(p[1] / p[0], 0.01, 1e-12);
}

}  // namespace
}  // namespace nimbus
