// The picture look against values worked by hand from docs/images.md: each
// tone mapping pinned at densities where its formula comes out round, a
// developed row whose pixels are those values (grey and coloured), and a
// single lit pixel whose glow reaches its neighbours by the weights of the
// three-box kernel.
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <vector>

#include "core/grid/image_look.h"
#include "tests/support/look_oracles.h"

namespace nimbus {
namespace {

double Tone(ToneMapping tone, double d, double dmin, double dmax, double gamma = 2.2) {
  LookParams look;
  look.tone = tone;
  look.gamma = gamma;
  return ToneMap(look, d, dmin, dmax);
}

// log(1+d)/log(1+max): ln 10 / ln 100 = 1/2, ln 4 / ln 16 = 1/2,
// ln 2 / ln 100 = log10(2) / 2.
TEST(LookOracle, LogToneMapIsLogOnePlusDOverLogOnePlusMax) {
  EXPECT_NEAR(Tone(ToneMapping::kLog, 9, 1, 99), 0.5, 1e-15);
  EXPECT_NEAR(Tone(ToneMapping::kLog, 3, 1, 15), 0.5, 1e-15);
  EXPECT_NEAR(Tone(ToneMapping::kLog, 1, 1, 99), 0.150514997831990598, 1e-15);
  EXPECT_NEAR(Tone(ToneMapping::kLog, 99, 1, 99), 1, 1e-15);
}

// (√d - √min)/(√max - √min): (2-1)/(3-1) = 1/2, (1.5-1)/(4-1) = 1/6; a
// picture whose lit pixels share one density is lit uniformly.
TEST(LookOracle, SqrtToneMapStretchesRootsBetweenTheExtremes) {
  EXPECT_NEAR(Tone(ToneMapping::kSqrt, 4, 1, 9), 0.5, 1e-15);
  EXPECT_NEAR(Tone(ToneMapping::kSqrt, 2.25, 1, 16), 1.0 / 6, 1e-15);
  EXPECT_NEAR(Tone(ToneMapping::kSqrt, 1, 1, 16), 0, 1e-15);
  EXPECT_EQ(Tone(ToneMapping::kSqrt, 5, 5, 5), 1);
}

// (d/max)^(1/γ): (1/4)^(1/2) = 1/2, (1/32)^(1/2.5) = 1/4; linear d/max.
TEST(LookOracle, GammaAndLinearToneMaps) {
  EXPECT_NEAR(Tone(ToneMapping::kGamma, 25, 1, 100, 2), 0.5, 1e-15);
  EXPECT_NEAR(Tone(ToneMapping::kGamma, 1, 1, 32, 2.5), 0.25, 1e-15);
  EXPECT_NEAR(Tone(ToneMapping::kLinear, 3, 1, 12), 0.25, 1e-15);
}

// One row of densities 0, 1, 9, 99 developed with the log map: background,
// log10(2)/2, 1/2 and 1, times the brightness; grey without colour.
TEST(LookOracle, DevelopedGreyRowIsTheLogMapTimesBrightness) {
  ImageDensity d;
  d.width = 4, d.height = 1;
  d.density = {0, 1, 9, 99};
  d.color = {0, 0.3f, 0.6f, 0.9f};
  LookParams look;
  look.tone = ToneMapping::kLog;
  look.colored = false;
  look.brightness = 1.5;
  look.background = {0.1, 0.2, 0.3};
  auto img = DevelopImage(d, look, nullptr);
  ASSERT_TRUE(img.ok()) << img.status();
  const double want[4] = {-1, 1.5 * 0.150514997831990598, 0.75, 1.5};
  for (int c = 0; c < 3; ++c) EXPECT_FLOAT_EQ(img->At(0, 0)[c], float(look.background[c]));
  for (int x = 1; x < 4; ++x)
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(img->At(x, 0)[c], want[x], 1e-6) << x << "," << c;
}

// A coloured pixel: the default sine palette at c = 1/4 (a = π/2, so
// sin(φ + a) = cos φ), mixed 40 % with its Rec. 709 grey, times v = 1/2
// (log map, d = 9 of max 99).
TEST(LookOracle, DevelopedColourIsPaletteMixedWithGreyTimesTone) {
  ImageDensity d;
  d.width = 2, d.height = 1;
  d.density = {9, 99};
  d.color = {0.25f, 0.25f};
  LookParams look;
  look.tone = ToneMapping::kLog;
  look.desaturation = 0.4;
  auto img = DevelopImage(d, look, nullptr);
  ASSERT_TRUE(img.ok()) << img.status();
  const double r = 0.4 + 0.25 * std::cos(0.5), g = 0.6 + 0.25 * std::cos(0.9),
               b = 0.7 + 0.25 * std::cos(1.3);
  const double grey = 0.2126 * r + 0.7152 * g + 0.0722 * b;
  const double want[3] = {0.6 * r + 0.4 * grey, 0.6 * g + 0.4 * grey, 0.6 * b + 0.4 * grey};
  for (int c = 0; c < 3; ++c) {
    EXPECT_NEAR(img->At(0, 0)[c], 0.5 * want[c], 1e-6) << c;
    EXPECT_NEAR(img->At(1, 0)[c], want[c], 1e-6) << c;
  }
}

// σ = 2: the three box widths for variances adding up to about σ² are
// 3, 3, 5 (ideal mean width √(4σ²+1) = 4.1 -> 3 and 5; two of 3 since
// (12σ² - 27 - 36 - 9)/(-16) rounds to 2). Their cascade is
// [1 2 3 2 1]/9 * [1 1 1 1 1]/5 = [1 3 6 8 9 8 6 3 1]/45 per axis.
TEST(LookOracle, OneLitPixelGlowsOntoItsNeighboursByTheKernelWeights) {
  const std::vector<double> k = testing::BoxCascadeKernel({3, 3, 5});
  const double hand[9] = {1, 3, 6, 8, 9, 8, 6, 3, 1};
  ASSERT_EQ(k.size(), 9u);
  for (int i = 0; i < 9; ++i) ASSERT_NEAR(k[size_t(i)], hand[i] / 45, 1e-15);
  RgbImage img;
  img.width = img.height = 17;
  img.rgb.assign(3 * 17 * 17, 0.f);
  for (int c = 0; c < 3; ++c) img.At(8, 8)[c] = 1.f;
  const double amount = 0.5;
  AddGlow(img, amount, 2);
  for (int y = 0; y < 17; ++y)
    for (int x = 0; x < 17; ++x) {
      const int dx = x - 8, dy = y - 8;
      double want = (dx == 0 && dy == 0) ? 1 : 0;
      if (std::abs(dx) <= 4 && std::abs(dy) <= 4)
        want += amount * k[size_t(dx + 4)] * k[size_t(dy + 4)];
      for (int c = 0; c < 3; ++c)
        ASSERT_NEAR(img.At(x, y)[c], want, 1e-6) << "pixel " << x << "," << y;
    }
}

// σ = 1: widths 1, 1, 3 (ideal √5 = 2.2 -> 1 and 3), so the glow is a
// 3 x 3 box: each of the eight neighbours gets amount / 9.
TEST(LookOracle, UnitRadiusGlowIsAThreeByThreeBox) {
  RgbImage img;
  img.width = 7, img.height = 5;
  img.rgb.assign(3 * 7 * 5, 0.f);
  img.At(3, 2)[1] = 0.9f;  // green only
  AddGlow(img, 1.0, 1);
  for (int y = 0; y < 5; ++y)
    for (int x = 0; x < 7; ++x) {
      const bool near = std::abs(x - 3) <= 1 && std::abs(y - 2) <= 1;
      const double want = (x == 3 && y == 2 ? 0.9 : 0) + (near ? 0.1 : 0);
      EXPECT_NEAR(img.At(x, y)[1], want, 1e-6) << x << "," << y;
      EXPECT_EQ(img.At(x, y)[0], 0.f);
      EXPECT_EQ(img.At(x, y)[2], 0.f);
    }
}

}  // namespace
}  // namespace nimbus
