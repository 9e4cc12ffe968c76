// Interpolation on one mesh and on sums of meshes, 1D to 4D: the
// interpolant passes exactly through the node values; the grid evaluator
// agrees with the point evaluator (which follows the reference description);
// pseudo n-cubic is C1 across cell faces and n-linear is not.
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "core/field/field_grid.h"
#include "core/field/field_recipe.h"
#include "tests/support/field_oracles.h"

namespace nimbus {
namespace {

constexpr FieldInterpolation kAll[] = {FieldInterpolation::kLinear,
                                       FieldInterpolation::kPseudoCubic,
                                       FieldInterpolation::kQuintic, FieldInterpolation::kCubic};

// One mesh of unit cells (n axes, `space` of them spatial), weight 1.
FractalFieldParams OneMesh(int dims, int space, FieldInterpolation interp) {
  FractalFieldParams p;
  p.dims = dims;
  p.mapping.space_dims = space;
  p.interpolation = interp;
  p.seed = 77;
  p.meshes.resize(1);
  return p;
}

TEST(FieldInterpolation, PassesExactlyThroughNodes) {
  for (auto interp : kAll)
    for (int dims = 1; dims <= 4; ++dims) {
      const int space = std::min(dims, 3);
      FractalField f(OneMesh(dims, space, interp));
      // Grid samples on integer points are nodes; time is a node too.
      FieldGrid g;
      for (int i = 0; i < space; ++i) {
        g.count[size_t(i)] = 6;
        g.origin[size_t(i)] = -2;
      }
      g.time = 3;
      std::vector<float> out(g.size());
      ASSERT_TRUE(EvaluateFieldGrid(f, g, out.data()).ok());
      for (int x = 0; x < g.count[0]; ++x)
        for (int y = 0; y < g.count[1]; ++y)
          for (int z = 0; z < g.count[2]; ++z) {
            int64_t node[4] = {x - 2, y - 2, z - 2, 0};
            for (int i = space; i < 3; ++i) node[i] = 0;
            if (dims > space) node[space] = 3;
            const float expected = f.Node(0, node);
            const size_t at = (size_t(x) * g.count[1] + y) * g.count[2] + z;
            ASSERT_EQ(out[at], expected) << "dims " << dims << " interp " << int(interp);
            const double p[3] = {double(x - 2), double(y - 2), double(z - 2)};
            ASSERT_EQ(f.Sample(p, 3), double(expected));
          }
    }
}

// Grid evaluation equals the point evaluator, for every dimension and
// interpolation, with offsets, non-unit cells, periods and a rotated mesh.
TEST(FieldInterpolation, GridMatchesPointEvaluator) {
  for (auto interp : kAll)
    for (int dims = 1; dims <= 4; ++dims) {
      const int space = std::min(dims, 3);
      FractalFieldParams p = testing::SeriesParams(dims, space, interp, {3.1, 2.7, 2.3, 1.9}, 4, 0,
                                                   5, WeightRule::kCellVolume);
      p.mapping.period[0] = 6.2;  // periodic x
      SnapCellsToPeriods(p, nullptr);
      if (space >= 2) {  // a rotated mesh uses the point path for itself
        FieldMesh r;
        r.cell = {1.3, 1.3, 1.3, 1.3};
        r.weight = 0.3;
        r.rotated = true;
        r.rotation = {{{0.8, -0.6, 0}, {0.6, 0.8, 0}, {0, 0, 1}}};
        p.mapping.period[0] = 0;
        for (auto& m : p.meshes) m.period_nodes[0] = 0;
        p.meshes.push_back(r);
      }
      ASSERT_TRUE(ValidateFieldParams(p).ok()) << ValidateFieldParams(p);
      FractalField f(p);
      FieldGrid g;
      for (int i = 0; i < space; ++i) {
        g.count[size_t(i)] = 9 - i;
        g.origin[size_t(i)] = -1.37 + i;
        g.step[size_t(i)] = 0.77;
      }
      g.time = 1.61;
      std::vector<float> out(g.size());
      ASSERT_TRUE(EvaluateFieldGrid(f, g, out.data()).ok());
      for (int x = 0; x < g.count[0]; ++x)
        for (int y = 0; y < g.count[1]; ++y)
          for (int z = 0; z < g.count[2]; ++z) {
            const double q[3] = {g.origin[0] + x * g.step[0], g.origin[1] + y * g.step[1],
                                 g.origin[2] + z * g.step[2]};
            const size_t at = (size_t(x) * g.count[1] + y) * g.count[2] + z;
            ASSERT_NEAR(out[at], f.Sample(q, g.time), 2e-5 * f.WeightSum())
                << "dims " << dims << " interp " << int(interp) << " at " << x << "," << y << ","
                << z;
          }
    }
}

// The largest jump of a directional derivative across the faces x = k
// (k integer) of a 2D or 3D single-mesh field, by one-sided differences.
double LargestSlopeJump(FieldInterpolation interp, int dims, int axis, double* typical) {
  FractalField f(OneMesh(dims, dims, interp));
  const double h = 1e-5;
  double worst = 0, sum = 0;
  int n = 0;
  for (int face = -3; face <= 3; ++face)
    for (double a = 0.13; a < 3; a += 0.37) {
      double p[3] = {a, 0.71 - a, 0.29 + a / 2};
      p[axis] = face;
      // Slopes along `axis` and along another axis, each side of the face.
      for (int dir : {axis, (axis + 1) % dims}) {
        auto eval = [&](double da, double dd) {
          double q[3] = {p[0], p[1], p[2]};
          q[axis] += da;
          q[dir] += dd;
          return f.Sample(q, 0);
        };
        double left, right;
        if (dir == axis) {
          left = (eval(0, 0) - eval(-h, 0)) / h;
          right = (eval(h, 0) - eval(0, 0)) / h;
        } else {
          left = (eval(-h, h) - eval(-h, -h)) / (2 * h);
          right = (eval(h, h) - eval(h, -h)) / (2 * h);
        }
        worst = std::max(worst, std::abs(left - right));
        sum += std::abs(left) + std::abs(right);
        n += 2;
      }
    }
  *typical = sum / n;
  return worst;
}

// Pseudo n-cubic (the reference's scheme) carries the derivatives along
// the axes still to come by linear interpolation, so its slope is
// continuous across the faces of the last axis but creases, less than
// n-linear's, across the others; the Catmull-Rom tensor is C1 everywhere.
TEST(FieldInterpolation, SlopeContinuityAcrossCellFaces) {
  for (int dims : {2, 3})
    for (int axis = 0; axis < dims; ++axis) {
      double typical = 0, ignored = 0;
      const double linear = LargestSlopeJump(FieldInterpolation::kLinear, dims, axis, &typical);
      const double pseudo = LargestSlopeJump(FieldInterpolation::kPseudoCubic, dims, axis, &ignored);
      const double cubic = LargestSlopeJump(FieldInterpolation::kCubic, dims, axis, &ignored);
      // One-sided differences with step 1e-5 err by O(1e-5) times the
      // curvature (a few units): 1e-3 of the typical slope is far above it.
      const double smooth = 1e-3 * typical;
      SCOPED_TRACE(::testing::Message() << "dims " << dims << " axis " << axis << ": linear "
                                      << linear << " pseudo " << pseudo << " cubic " << cubic);
      EXPECT_GT(linear, 0.1 * typical) << "n-linear creases on every face";
      EXPECT_LT(cubic, smooth);
      if (axis == dims - 1)
        EXPECT_LT(pseudo, smooth);
      else
        EXPECT_LT(pseudo, linear);
    }
}

}  // namespace
}  // namespace nimbus
