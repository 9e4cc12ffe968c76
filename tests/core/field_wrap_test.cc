// Periodic wrapping is bitwise exact: across a tile edge, and for a loop,
// whose frame `frames` equals frame 0 bit for bit; and the loop is
// seamless in the mathematics too, not only by renumbering frames.
#include <gtest/gtest.h>

#include <cstring>
#include <vector>

#include "core/field/field_grid.h"
#include "core/field/field_plan.h"
#include "core/field/field_recipe.h"
#include "tests/support/field_oracles.h"

namespace nimbus {
namespace {

FractalFieldParams Periodic(int dims, FieldInterpolation interp) {
  FractalFieldParams p = testing::SeriesParams(dims, 2, interp, {0.5, 0.5, 2, 0}, 6, 0.8, 9);
  p.mapping.period[0] = 1;
  p.mapping.period[1] = 1;
  return p;
}

TEST(FieldWrap, TileEdgeIsBitwiseExact) {
  for (auto interp : {FieldInterpolation::kLinear, FieldInterpolation::kPseudoCubic,
                      FieldInterpolation::kQuintic}) {
    FractalFieldParams p = Periodic(2, interp);
    std::vector<std::string> notes;
    SnapCellsToPeriods(p, &notes);
    ASSERT_TRUE(ValidateFieldParams(p).ok());
    FractalField f(p);
    // Two periods side by side on a binary grid: sample i and i + 64 are
    // the same point of the torus.
    FieldGrid g;
    g.count = {128, 128, 1};
    g.step = {1.0 / 64, 1.0 / 64, 1};
    g.origin = {-0.5, 3.0, 0};
    std::vector<float> out(g.size());
    ASSERT_TRUE(EvaluateFieldGrid(f, g, out.data()).ok());
    for (int x = 0; x < 64; ++x)
      for (int y = 0; y < 64; ++y) {
        const float v = out[size_t(x) * 128 + y];
        ASSERT_EQ(v, out[size_t(x + 64) * 128 + y]);
        ASSERT_EQ(v, out[size_t(x) * 128 + y + 64]);
        ASSERT_EQ(v, out[size_t(x + 64) * 128 + y + 64]);
      }
  }
}

TEST(FieldWrap, LoopFrameEqualsFirstFrameBitwise) {
  // A 3D field (x, y, t) with linear wind: 16 frames of 0.25, so the time
  // period is 4; the wind moves the field by exactly one period over the
  // loop.
  FractalFieldParams p = Periodic(3, FieldInterpolation::kPseudoCubic);
  FieldAnimation a;
  a.frames = 16;
  a.time_step = 0.25;
  a.loop = true;
  p.mapping.period[2] = double(a.frames) * a.time_step;
  p.mapping.wind.kind = WindKind::kLinear;
  p.mapping.wind.velocity = {-0.25, 0, 0};  // -0.25 * 4 = -1 period
  SnapCellsToPeriods(p, nullptr);
  ASSERT_TRUE(ValidateFieldParams(p).ok());
  FractalField f(p);
  FieldGrid g;
  g.count = {48, 40, 1};
  g.step = {1.0 / 48, 1.0 / 40, 1};
  auto frame = [&](double t) {
    FieldGrid h = g;
    h.time = t;
    std::vector<float> out(h.size());
    EXPECT_TRUE(EvaluateFieldGrid(f, h, out.data()).ok());
    return out;
  };
  EXPECT_EQ(FrameTime(a, 16), FrameTime(a, 0));
  EXPECT_EQ(FrameTime(a, 17), FrameTime(a, 1));
  const auto first = frame(FrameTime(a, 0));
  const auto again = frame(FrameTime(a, 16));
  EXPECT_EQ(0, std::memcmp(first.data(), again.data(), first.size() * sizeof(float)));
  // Without renumbering, t = 4 is the same field up to rounding: the
  // lattice repeats in time and the wind has moved one whole period.
  const auto unwrapped = frame(16 * 0.25);
  const auto last = frame(FrameTime(a, 15));
  double diff = 0, step = 0;
  for (size_t i = 0; i < first.size(); ++i) {
    diff = std::max(diff, double(std::abs(unwrapped[i] - first[i])));
    step = std::max(step, double(std::abs(last[i] - first[i])));
  }
  EXPECT_LT(diff, 1e-5);
  EXPECT_GT(step, 1e-3);  // consecutive frames do differ
}

}  // namespace
}  // namespace nimbus
