// Fractal fields against closed forms (docs/fractal_fields.md): the quintic
// fade 6t^5 - 15t^4 + 10t^3 worked by hand, a quintic mesh that is the
// eased blend of its two nodes with zero slope on every cell face, and a
// field under wind that equals the still field displaced by the wind's
// δ(t), at times that are no whole period, through the point and the grid
// evaluators.
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "core/field/field_grid.h"
#include "core/field/fractal_field.h"

namespace nimbus {
namespace {

// The fade written out independently of the engine's Horner form.
double Fade(double t) { return 6 * std::pow(t, 5) - 15 * std::pow(t, 4) + 10 * std::pow(t, 3); }

FractalFieldParams OneQuinticMesh(int dims, double cell) {
  FractalFieldParams p;
  p.dims = dims;
  p.mapping.space_dims = dims;
  p.interpolation = FieldInterpolation::kQuintic;
  p.seed = 123;
  p.meshes.resize(1);
  p.meshes[0].cell = {cell, cell, cell, cell};
  return p;
}

// 6/1024 - 15/256 + 10/64 = 106/1024; symmetric about 1/2.
TEST(FieldOracle, QuinticFadeValuesWorkedByHand) {
  EXPECT_DOUBLE_EQ(QuinticFade(0.25), 106.0 / 1024);
  EXPECT_DOUBLE_EQ(QuinticFade(0.5), 0.5);
  EXPECT_DOUBLE_EQ(QuinticFade(0.75), 918.0 / 1024);
  EXPECT_EQ(QuinticFade(0), 0);
  EXPECT_EQ(QuinticFade(1), 1);
  // Its slope 30t^2(t-1)^2 vanishes at both ends: one-sided differences.
  const double h = 1e-4;
  EXPECT_LT(QuinticFade(h) / h, 1e-6);
  EXPECT_LT((1 - QuinticFade(1 - h)) / h, 1e-6);
}

// A 1D quintic mesh of cell 0.5 between nodes k and k+1 is
// n_k + (n_{k+1} - n_k) · Fade(t), by the point and the grid evaluators.
TEST(FieldOracle, QuinticMeshIsTheEasedBlendOfItsNodes) {
  FractalField f(OneQuinticMesh(1, 0.5));
  FieldGrid g;
  g.count = {24, 1, 1};
  g.origin = {-3 + 0.5 * 0.3, 0, 0};  // t = 0.3 in every cell
  g.step = {0.5, 1, 1};
  std::vector<float> grid(g.size());
  ASSERT_TRUE(EvaluateFieldGrid(f, g, grid.data()).ok());
  for (int i = 0; i < 24; ++i) {
    const int64_t k = i - 6;
    const int64_t n0[1] = {k}, n1[1] = {k + 1};
    const double a = f.Node(0, n0), b = f.Node(0, n1);
    for (double t : {0.1, 0.3, 0.5, 0.85}) {
      const double x = 0.5 * (double(k) + t);
      EXPECT_NEAR(f.Sample(&x, 0), a + (b - a) * Fade(t), 1e-12) << "cell " << k << " t " << t;
    }
    EXPECT_NEAR(grid[size_t(i)], a + (b - a) * Fade(0.3), 1e-6) << "grid sample " << i;
  }
}

// A 2D quintic mesh is flat across every face, along the face's normal:
// the one-sided slopes on both sides are O(h^2), where n-linear's are the
// node differences.
TEST(FieldOracle, QuinticSlopeIsZeroOnCellFaces) {
  FractalField f(OneQuinticMesh(2, 1));
  const double h = 1e-4;
  double largest = 0, node_step = 0;
  for (int face = -3; face <= 3; ++face)
    for (double across = 0.15; across < 3; across += 0.4)
      for (int axis = 0; axis < 2; ++axis) {
        double p[2] = {across, across};
        p[axis] = face;
        auto at = [&](double d) {
          double q[2] = {p[0], p[1]};
          q[axis] += d;
          return f.Sample(q, 0);
        };
        largest = std::max({largest, std::abs(at(h) - at(0)) / h, std::abs(at(0) - at(-h)) / h});
        int64_t a[2] = {int64_t(std::floor(p[0])), int64_t(std::floor(p[1]))};
        int64_t b[2] = {a[0], a[1]};
        ++b[axis];
        node_step = std::max(node_step, double(std::abs(f.Node(0, b) - f.Node(0, a))));
      }
  ASSERT_GT(node_step, 0.1);  // a linear blend would slope this much
  EXPECT_LT(largest, 1e-5);
}

FractalFieldParams Windy(WindKind kind, int dims) {
  FractalFieldParams p;
  p.dims = dims;
  p.mapping.space_dims = 3;
  p.interpolation = FieldInterpolation::kLinear;
  p.seed = 9;
  p.meshes.resize(2);
  p.meshes[0].cell = {0.5, 0.5, 0.5, 1};
  p.meshes[1].cell = {0.25, 0.25, 0.25, 0.5};
  p.meshes[1].offset = {0.3, 0.1, 0.7, 0.2};
  p.meshes[1].weight = 0.5;
  p.mapping.wind.kind = kind;
  p.mapping.wind.velocity = {0.25, -0.5, 0.125};
  p.mapping.wind.amplitude = {0.2, 0, -0.1};
  p.mapping.wind.sine_period = 1.2;
  p.mapping.wind.phase_radians = M_PI / 6;
  return p;
}

// Wind δ(t) moves field coordinates: F_wind(x, t) = F_still(x + δ(t), t).
// Linear δ = v·t; sine δ = A·sin(2π t / P + φ), at t = 0.3 of P = 1.2
// and φ = 30°: sin(90° + 30°) = √3/2.
TEST(FieldOracle, WindIsTheStillFieldDisplacedByDelta) {
  for (int dims : {3, 4}) {
    FractalField linear(Windy(WindKind::kLinear, dims)), sine(Windy(WindKind::kSine, dims)),
        still(Windy(WindKind::kNone, dims));
    int differs = 0;
    for (double t : {0.37, 1.5}) {
      const double vt[3] = {0.25 * t, -0.5 * t, 0.125 * t};
      for (double a = -1.1; a < 1.2; a += 0.31) {
        const double x[3] = {a, 0.7 - a, 0.2 + 0.5 * a};
        const double moved[3] = {x[0] + vt[0], x[1] + vt[1], x[2] + vt[2]};
        EXPECT_NEAR(linear.Sample(x, t), still.Sample(moved, t), 1e-12) << dims << "D t " << t;
        differs += std::abs(linear.Sample(x, t) - still.Sample(x, t)) > 1e-3;
      }
    }
    EXPECT_GT(differs, 8) << "the wind moves the field";
    const double s = std::sqrt(3) / 2;
    for (double a = -1.1; a < 1.2; a += 0.31) {
      const double x[3] = {a, 0.7 - a, 0.2 + 0.5 * a};
      const double moved[3] = {x[0] + 0.2 * s, x[1], x[2] - 0.1 * s};
      EXPECT_NEAR(sine.Sample(x, 0.3), still.Sample(moved, 0.3), 1e-12) << dims << "D";
    }
  }
}

// The grid evaluator: at t = 1.5 the linear wind moves x by 0.375 = three
// steps of 0.125, so the windy grid is the still grid read three samples on.
TEST(FieldOracle, WindyGridIsTheStillGridShiftedBySamples) {
  FractalFieldParams p = Windy(WindKind::kLinear, 3);
  p.mapping.wind.velocity = {0.25, 0, 0};
  FractalFieldParams q = p;
  q.mapping.wind.kind = WindKind::kNone;
  FractalField windy(p), still(q);
  FieldGrid g;
  g.count = {16, 5, 4};
  g.origin = {-1, -0.5, 0.25};
  g.step = {0.125, 0.125, 0.125};
  g.time = 1.5;
  std::vector<float> a(g.size()), b(g.size());
  ASSERT_TRUE(EvaluateFieldGrid(windy, g, a.data()).ok());
  ASSERT_TRUE(EvaluateFieldGrid(still, g, b.data()).ok());
  size_t moved = 0;
  for (int x = 0; x + 3 < 16; ++x)
    for (int y = 0; y < 5; ++y)
      for (int z = 0; z < 4; ++z) {
        const size_t i = (size_t(x) * 5 + size_t(y)) * 4 + size_t(z);
        const size_t j = (size_t(x + 3) * 5 + size_t(y)) * 4 + size_t(z);
        ASSERT_NEAR(a[i], b[j], 1e-6) << x << "," << y << "," << z;
        moved += std::abs(a[i] - b[i]) > 1e-3;
      }
  EXPECT_GT(moved, 50u);  // the shift is visible: not a field constant in x
}

}  // namespace
}  // namespace nimbus
