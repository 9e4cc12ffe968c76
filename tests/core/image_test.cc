// Pictures of the chaos game (docs/images.md): counted into folded pixel
// counters, box-filtered, tone mapped, coloured, glowed and written with
// libpng and OpenEXR.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <random>
#include <vector>

#include "core/chaos/auto_frame.h"
#include "core/chaos/chaos_game.h"
#include "core/chaos/image_plane.h"
#include "core/grid/image_look.h"
#include "core/io/image_io.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

// The Sierpinski triangle on (0,0), (1,0), (0,1) in the z = 0 plane.
ChaosGameParams Sierpinski(uint64_t iterations) {
  ChaosGameParams p;
  for (Vec3 t : {Vec3{0, 0, 0}, Vec3{0.5, 0, 0}, Vec3{0, 0.5, 0}}) {
    PointMap m;
    m.pre = Affine3::Translate(t) * Affine3::Scale({0.5, 0.5, 0.5});
    p.ifs.maps.push_back(m);
    p.ifs.probabilities.push_back(1.0 / 3);
  }
  p.frame.resolution = {64, 64, 4};
  p.frame.bounds = {{-0.1, -0.1, -0.1}, {1.1, 1.1, 0.1}};
  p.iterations = iterations;
  p.seed = 7;
  return p;
}

CountGrid RunImage(ChaosGameParams p, int threads) {
  auto game = ChaosGame::Create(std::move(p), threads);
  EXPECT_TRUE(game.ok()) << game.status();
  EXPECT_TRUE((*game)->Run(nullptr).ok());
  return (*game)->TakeCounts();
}

std::vector<uint32_t> Pixels(const CountGrid& g, int w, int h) {
  std::vector<uint32_t> out;
  for (int r = 0; r < h; ++r)
    for (int c = 0; c < w; ++c) {
      const Int3 v = FoldedImageVoxel(c, r);
      out.push_back(g.Get(v.x, v.y, v.z));
    }
  return out;
}

// Pixel buffers from 1 MiB on are fresh huge-page-aligned mappings (zero,
// and resize writes nothing); smaller ones come from the heap; copies and
// growth keep the values.
TEST(PixelBuffer, LargeBuffersAreFreshAlignedMappings) {
  const size_t n = (size_t{3} << 20) / sizeof(float);
  PixelBuffer big;
  big.resize(n);
  EXPECT_EQ(reinterpret_cast<uintptr_t>(big.data()) % ZeroPages::kHugePage, 0u);
  for (size_t i = 0; i < n; i += 1000) ASSERT_EQ(big[i], 0.f);
  for (size_t i = 0; i < n; ++i) big[i] = float(i % 977);
  PixelBuffer copy = big;
  copy.resize(2 * n);  // moves into a new mapping
  for (size_t i = 0; i < n; i += 997) ASSERT_EQ(copy[i], float(i % 977));
  PixelBuffer small(100, 2.5f);
  EXPECT_EQ(small[99], 2.5f);
}

TEST(ImagePlane, AxisZDrawsThePlaneUprightWithSquarePixels) {
  ImageView view;  // axis Z
  const Bounds box{{0, 0, -1}, {2, 1, 1}};
  EXPECT_EQ(DefaultImageHeight(view, box, 200), 100);
  const ImagePlane plane = MakeImagePlane(view, box, 200, 100);
  double fx, fy;
  ASSERT_TRUE(plane.Project({0.01, 0.99, 0}, &fx, &fy));
  EXPECT_NEAR(fx, 1, 1e-9);  // left
  EXPECT_NEAR(fy, 1, 1e-9);  // top row: +y is up
  ASSERT_TRUE(plane.Project({1.995, 0.005, 0.5}, &fx, &fy));
  EXPECT_NEAR(fx, 199.5, 1e-9);
  EXPECT_NEAR(fy, 99.5, 1e-9);
  EXPECT_FALSE(plane.Project({1, 0.5, 1.5}, &fx, &fy));  // outside the depth clip
  // The box clips depth as the volume does: [min, max).
  EXPECT_TRUE(plane.Project({1, 0.5, -1}, &fx, &fy));
  EXPECT_FALSE(plane.Project({1, 0.5, 1}, &fx, &fy));
  // A wider picture than the box: the box is centred, pixels stay square.
  const ImagePlane wide = MakeImagePlane(view, box, 400, 100);
  ASSERT_TRUE(wide.Project({0, 0.5, 0}, &fx, &fy));
  EXPECT_NEAR(fx, 100, 1e-9);
  EXPECT_NEAR(fy, 50, 1e-9);
}

TEST(ImagePlane, PerspectiveCameraCentresItsTarget) {
  ImageView view;
  view.camera = view.perspective = true;
  view.position = {0, 0, 5};
  view.look_at = {0, 0, 0};
  view.fov_degrees = 90;
  const ImagePlane plane = MakeImagePlane(view, {{-1, -1, -1}, {1, 1, 1}}, 100, 100);
  double fx, fy;
  ASSERT_TRUE(plane.Project({0, 0, 0}, &fx, &fy));
  EXPECT_NEAR(fx, 50, 1e-9);
  EXPECT_NEAR(fy, 50, 1e-9);
  // 45 degrees off axis reaches the edge with a 90-degree field of view.
  ASSERT_TRUE(plane.Project({0, 2.5, 2.5 - 1e-6}, &fx, &fy) || fy < 0);
  EXPECT_NEAR(fy, 0, 1e-3);
  EXPECT_FALSE(plane.Project({0, 0, 6}, &fx, &fy));  // behind the eye
}

TEST(ImagePlane, InverseUndoesAnAffineMap) {
  const Affine3 a =
      Affine3::Translate({1, -2, 3}) * Affine3::Rotate({1, 2, 3}, 40) * Affine3::Scale({2, 0.5, 3});
  const Vec3 p{0.3, -0.7, 1.1};
  const Vec3 q = Inverse(a).Apply(a.Apply(p));
  EXPECT_NEAR(q.x, p.x, 1e-12);
  EXPECT_NEAR(q.y, p.y, 1e-12);
  EXPECT_NEAR(q.z, p.z, 1e-12);
}

// A constant map puts every point on one pixel: the fast path (conjugated
// into pixel space, rows folded by the SIMD kernels) and the general path
// (colour on, projected per point) must both find it, including rows past
// the first 32 and past the first tile of 1024.
TEST(ImageCounting, EveryPathLandsOnTheRightPixel) {
  for (const Vec3 target : {Vec3{0.25, 0.75, 0}, Vec3{0.9, 0.01, 0}}) {
    ChaosGameParams p = Sierpinski(100'000);
    p.ifs.maps.resize(1);
    p.ifs.probabilities = {1};
    p.ifs.maps[0].pre = Affine3::Translate(target) * Affine3::Scale({0, 0, 0});
    const int w = 300, h = 2100;
    p.image = MakeImagePlane(ImageView{}, p.frame.bounds, w, h);
    double fx, fy;
    ASSERT_TRUE(p.image->Project(target, &fx, &fy));
    for (const SimdLevel simd : {SimdLevel::kScalar, DetectSimd()}) {
      for (const bool color : {false, true}) {
        ChaosGameParams q = p;
        q.simd = simd;
        if (color) q.color.mode = ColorMode::kAddress;
        ASSERT_EQ(ChaosGame::UsesFastPath(q), !color);
        const CountGrid g = RunImage(q, 2);
        const Int3 v = FoldedImageVoxel(int(fx), int(fy));
        EXPECT_EQ(g.Get(v.x, v.y, v.z), 100'000u) << "colour " << color << " row " << fy;
        EXPECT_EQ(g.Total(), 100'000u);
      }
    }
  }
}

TEST(ImageCounting, SameCountsForAnyThreadCount) {
  for (const bool color : {false, true}) {
    ChaosGameParams p = Sierpinski(3'000'000);
    if (color) p.color.mode = ColorMode::kAddress;
    p.image = MakeImagePlane(ImageView{}, p.frame.bounds, 160, 90);
    const CountGrid a = RunImage(p, 1), b = RunImage(p, 2);
    EXPECT_EQ(Pixels(a, 160, 90), Pixels(b, 160, 90));
    EXPECT_GT(a.Total(), 2'900'000u);
  }
}

// One sample per pixel takes a path of its own: the counts and mean
// colours of two summed parts, pixel for pixel against the counters read
// one by one, across partial tile columns (70 = 2 x 32 + 6), the tile
// rows past row 1024, unallocated tiles, and a part without colour.
TEST(ImageLook, OneSamplePerPixelIsEachPixelsCounters) {
  const int w = 70, h = 1100;
  const Int3 res = FoldedImageResolution(w, h);
  std::vector<CountGrid> parts;
  parts.emplace_back(res, true);
  parts.emplace_back(res, true);
  std::mt19937 rng(11);
  for (int k = 0; k < 20000; ++k) {
    const int x = int(rng() % 40), row = int(rng() % uint32_t(h));  // columns 40+ stay empty
    const Int3 v = FoldedImageVoxel(x, row);
    const uint32_t c16 = rng() % (CountGrid::kColorScale + 1);
    parts[k % 2].AddKey(CountGrid::WithColor(parts[0].Key(v.x, v.y, v.z), c16), 1 + rng() % 3);
  }
  CountGrid grey(res, false);
  const Int3 corner = FoldedImageVoxel(69, 1099);
  grey.Add(corner.x, corner.y, corner.z, 5);
  for (bool coloured : {true, false}) {
    std::vector<const CountGrid*> ptrs;
    if (coloured)
      ptrs = {&parts[0], &parts[1]};
    else
      ptrs = {&grey};
    auto d = BoxFilterImage(ptrs, w, h, 1, 1, nullptr);
    ASSERT_TRUE(d.ok()) << d.status();
    ASSERT_EQ(d->width, w);
    ASSERT_EQ(d->height, h);
    for (int row = 0; row < h; ++row)
      for (int x = 0; x < w; ++x) {
        const Int3 v = FoldedImageVoxel(x, row);
        uint64_t sum = 0, col = 0;
        for (const CountGrid* g : ptrs) {
          sum += g->Get(v.x, v.y, v.z);
          col += g->GetColorSum(v.x, v.y, v.z);
        }
        const size_t p = size_t(row) * w + size_t(x);
        ASSERT_EQ(d->density[p], float(double(sum))) << x << ", " << row;
        const float want = sum ? float(double(col) / (double(sum) * CountGrid::kColorScale)) : 0.f;
        ASSERT_EQ(d->color[p], want) << x << ", " << row;
      }
  }
}

TEST(ImageLook, SupersampledEqualsTheDoubleSizeBoxFilteredDown) {
  ChaosGameParams p = Sierpinski(4'000'000);
  p.color.mode = ColorMode::kAddress;
  const int w = 61, h = 47;  // odd sizes: blocks straddle tiles
  // Width w with 2 x 2 supersampling counts on the plane of a 2w x 2h picture.
  p.image = MakeImagePlane(ImageView{}, p.frame.bounds, 2 * w, 2 * h);
  const CountGrid counts = RunImage(p, 2);
  auto ss = BoxFilterImage({&counts}, 2 * w, 2 * h, 2, 2, nullptr);
  auto full = BoxFilterImage({&counts}, 2 * w, 2 * h, 1, 1, nullptr);
  ASSERT_TRUE(ss.ok() && full.ok());
  ASSERT_EQ(ss->width, w);
  ASSERT_EQ(ss->height, h);
  for (int r = 0; r < h; ++r)
    for (int c = 0; c < w; ++c) {
      double d = 0;
      for (int j = 0; j < 2; ++j)
        for (int i = 0; i < 2; ++i) d += full->density[size_t(2 * r + j) * 2 * w + 2 * c + i];
      EXPECT_EQ(ss->density[size_t(r) * w + c], float(d / 4)) << c << "," << r;
    }
}

TEST(ImageLook, SinePaletteFollowsTheFormula) {
  const Palette sine;
  for (double t : {0.0, 0.1, 0.37, 0.5, 0.99, 1.0}) {
    const double a = 2 * std::numbers::pi * t;
    const Vec3 c = sine.Eval(t);
    EXPECT_DOUBLE_EQ(c.x, 0.4 + 0.25 * std::sin(0.5 + a));
    EXPECT_DOUBLE_EQ(c.y, 0.6 + 0.25 * std::sin(0.9 + a));
    EXPECT_DOUBLE_EQ(c.z, 0.7 + 0.25 * std::sin(1.3 + a));
  }
  const Palette grad({{0, {1, 0, 0}}, {1, {0, 0, 1}}});
  const Vec3 mid = grad.Eval(0.25);
  EXPECT_DOUBLE_EQ(mid.x, 0.75);
  EXPECT_DOUBLE_EQ(mid.z, 0.25);
}

TEST(ImageLook, ToneMappingIsMonotoneAndReachesOne) {
  for (ToneMapping tone :
       {ToneMapping::kSqrt, ToneMapping::kLog, ToneMapping::kGamma, ToneMapping::kLinear}) {
    LookParams look;
    look.tone = tone;
    double last = 0;
    for (double d = 0.5; d <= 1000; d *= 1.3) {
      const double v = ToneMap(look, d, 0.5, 1000);
      EXPECT_GE(v, last);
      EXPECT_LE(v, 1);
      last = v;
    }
    EXPECT_DOUBLE_EQ(ToneMap(look, 1000, 0.5, 1000), 1);
    EXPECT_EQ(ToneMap(look, 0, 0.5, 1000), 0);
  }
  LookParams sqrt_look;
  EXPECT_DOUBLE_EQ(ToneMap(sqrt_look, 0.5, 0.5, 1000), 0);  // the seed's min/max normalisation
}

ImageDensity Blob(int w, int h) {
  ImageDensity d;
  d.width = w, d.height = h;
  for (int r = 0; r < h; ++r)
    for (int c = 0; c < w; ++c) {
      d.density.push_back(float((c * 7 + r * 3) % 11));
      d.color.push_back(float(c) / float(w));
    }
  return d;
}

TEST(ImageLook, GlowAtZeroIsTheIdentityAndAddsLightOtherwise) {
  LookParams look;
  look.desaturation = 0.3;
  auto plain = DevelopImage(Blob(40, 30), look, nullptr);
  ASSERT_TRUE(plain.ok());
  RgbImage same = *plain;
  AddGlow(same, 0, 5);
  EXPECT_EQ(same.rgb, plain->rgb);
  AddGlow(same, 0.5, 0);
  EXPECT_EQ(same.rgb, plain->rgb);
  RgbImage glowing = *plain;
  AddGlow(glowing, 0.5, 3);
  double before = 0, after = 0;
  for (size_t i = 0; i < plain->rgb.size(); ++i) {
    EXPECT_GE(glowing.rgb[i], plain->rgb[i]);
    before += plain->rgb[i], after += glowing.rgb[i];
  }
  // The blur keeps the light (edges clamped), so half of it is added.
  EXPECT_NEAR(after / before, 1.5, 0.02);
}

// The develop's batched palette sines and their rounding guard give the
// floats of the per-pixel formula (tone map, Eval, grey mix, brightness),
// on three million channels with tones, mixes and brightnesses of all
// kinds, and with a palette of stops.
TEST(ImageLook, DevelopMatchesThePerPixelFormula) {
  ImageDensity d;
  d.width = 1000, d.height = 250;
  d.density.resize(size_t(d.width) * d.height);
  d.color.resize(d.density.size());
  std::mt19937 rng(9);
  for (size_t i = 0; i < d.density.size(); ++i) {
    d.density[i] = i % 7 == 0 ? 0.0f : float(std::exp2(double(rng() % 20000) / 1000.0 - 4));
    d.color[i] = float(double(rng()) / 4294967296.0);
  }
  float dmin = 0, dmax = 0;
  for (float x : d.density)
    if (x > 0) dmin = dmin > 0 ? std::min(dmin, x) : x, dmax = std::max(dmax, x);
  struct Case {
    ToneMapping tone;
    double desaturation, brightness;
    bool stops;
  };
  for (const Case c :
       {Case{ToneMapping::kSqrt, 0, 1, false}, Case{ToneMapping::kLog, 0.3, 2.5, false},
        Case{ToneMapping::kGamma, 1, 0.7, false}, Case{ToneMapping::kLinear, 0.5, 1, true}}) {
    LookParams look;
    look.tone = c.tone;
    look.desaturation = c.desaturation;
    look.brightness = c.brightness;
    look.background = {0.1, 0.2, 0.3};
    if (c.stops) look.palette = Palette({{0, {1, 0, 0}}, {0.4, {0, 1, 0.5}}, {1, {0.2, 0.1, 1}}});
    auto got = DevelopImage(d, look, nullptr);
    ASSERT_TRUE(got.ok());
    size_t differing = 0;
    for (int row = 0; row < d.height; ++row)
      for (int x = 0; x < d.width; ++x) {
        const size_t p = size_t(row) * size_t(d.width) + size_t(x);
        float want[3];
        if (!(d.density[p] > 0)) {
          for (int k = 0; k < 3; ++k) want[k] = float(look.background[k]);
        } else {
          const double v = look.brightness * ToneMap(look, d.density[p], dmin, dmax);
          Vec3 col = look.palette.Eval(d.color[p]);
          const double grey = 0.2126 * col.x + 0.7152 * col.y + 0.0722 * col.z;
          col = (1 - look.desaturation) * col + look.desaturation * Vec3{grey, grey, grey};
          for (int k = 0; k < 3; ++k) want[k] = float(col[k] * v);
        }
        for (int k = 0; k < 3; ++k) differing += got->At(x, row)[k] != want[k];
      }
    EXPECT_EQ(differing, 0u) << "tone " << int(c.tone) << " desaturation " << c.desaturation;
  }
}

// The guard: values closer to a float's rounding boundary than the margin
// are refused, farther ones accepted, on both sides and for negatives.
TEST(ImageLook, RoundsAlikeRefusesValuesNearARoundingBoundary) {
  using palette_internal::RoundsAlike;
  for (float f : {1.0f, 0.7f, 3.25e-5f, 1234.5f, -0.3f}) {
    const float next = std::nextafter(f, f > 0 ? 2 * f : 2 * f);
    const double mid = (double(f) + double(next)) / 2, gap = std::fabs(double(next) - f);
    const double margin = gap * 1e-6;
    EXPECT_FALSE(RoundsAlike(mid, 0)) << f;  // a tie
    const double inward = mid > 0 ? -1 : 1;  // towards f
    EXPECT_FALSE(RoundsAlike(mid + inward * margin / 2, margin)) << f;
    EXPECT_TRUE(RoundsAlike(mid + inward * margin * 2, margin)) << f;
    EXPECT_TRUE(RoundsAlike(double(f), margin)) << f;
  }
  EXPECT_TRUE(RoundsAlike(0.0, 0));
  EXPECT_FALSE(RoundsAlike(0.0, 1e-30));
  EXPECT_FALSE(RoundsAlike(1e300, 1));
  EXPECT_FALSE(RoundsAlike(1e-60, 1e-80));  // rounds to zero
}

TEST(ImageLook, DesaturationMixesWithGrey) {
  ImageDensity one;
  one.width = one.height = 1;
  one.density = {1};
  one.color = {0.2f};
  LookParams look;
  look.desaturation = 1;
  auto grey = DevelopImage(one, look, nullptr);
  ASSERT_TRUE(grey.ok());
  EXPECT_FLOAT_EQ(grey->rgb[0], grey->rgb[1]);
  EXPECT_FLOAT_EQ(grey->rgb[1], grey->rgb[2]);
  look.desaturation = 0;
  auto colour = DevelopImage(one, look, nullptr);
  const Vec3 want = Palette().Eval(double(0.2f));
  EXPECT_FLOAT_EQ(colour->rgb[0], float(want.x));
  EXPECT_FLOAT_EQ(colour->rgb[2], float(want.z));
}

TEST(ImageFiles, PngAndExrReadBackWithTheirLibraries) {
  testing::TempDir dir;
  RgbImage img;
  img.width = 37, img.height = 23;
  for (int i = 0; i < 37 * 23 * 3; ++i) img.rgb.push_back(float((i * 13) % 101) / 100.f);
  img.rgb[0] = 1.5f;  // clamped in PNG, kept in EXR
  ASSERT_TRUE(WriteImage(dir / "a.png", img, ImageFormat::kPng8).ok());
  ASSERT_TRUE(WriteImage(dir / "b.png", img, ImageFormat::kPng16).ok());
  ASSERT_TRUE(WriteImage(dir / "c.exr", img, ImageFormat::kExr).ok());
  for (auto [name, depth] : {std::pair{"a.png", 8}, std::pair{"b.png", 16}}) {
    auto png = ReadPngPixels(dir / name);
    ASSERT_TRUE(png.ok()) << png.status();
    EXPECT_EQ(png->width, 37);
    EXPECT_EQ(png->height, 23);
    EXPECT_EQ(png->bit_depth, depth);
    EXPECT_EQ(png->channels, 3);
    const double max = depth == 8 ? 255 : 65535;
    EXPECT_EQ(png->samples[0], uint16_t(max));
    for (size_t i = 1; i < img.rgb.size(); ++i)
      ASSERT_EQ(png->samples[i], uint16_t(std::lround(img.rgb[i] * max))) << i;
  }
  auto exr = ReadExr(dir / "c.exr");
  ASSERT_TRUE(exr.ok()) << exr.status();
  EXPECT_EQ(exr->width, 37);
  EXPECT_EQ(exr->height, 23);
  EXPECT_EQ(exr->rgb, img.rgb);
  auto bytes = EncodePng8(img);
  ASSERT_TRUE(bytes.ok());
  EXPECT_EQ(bytes->substr(1, 3), "PNG");
  // Same picture, same bytes.
  ASSERT_TRUE(WriteImage(dir / "a2.png", img, ImageFormat::kPng8).ok());
  EXPECT_EQ(testing::ReadFileBytes(dir / "a.png"), testing::ReadFileBytes(dir / "a2.png"));
}

// Samples on and next to every rounding boundary of both depths, and the
// odd ones (NaN, -0, below 0, above 1), quantise as std::lround of the
// clamped value does.
TEST(ImageFiles, PngSamplesRoundAsLroundOnEveryBoundary) {
  testing::TempDir dir;
  std::vector<float> values = {
      std::nanf(""), -0.f, -1e-30f, -3.f, 1.f, 2.f, std::numeric_limits<float>::infinity(), 0.f};
  for (double max : {255.0, 65535.0})
    for (int k = 0; k <= 200; ++k) {
      // Halfway between steps k and k + 1 (and near the top of the range).
      const int step = k < 100 ? k : int(max) - 200 + k;
      const float half = float((step + 0.5) / max);
      for (float v : {half, std::nextafter(half, 0.f), std::nextafter(half, 2.f)})
        values.push_back(v);
    }
  RgbImage img;
  img.width = 1, img.height = int(values.size() + 2) / 3;
  img.rgb.assign(3 * size_t(img.height), 0.f);
  std::copy(values.begin(), values.end(), img.rgb.begin());
  for (auto [format, max] :
       {std::pair{ImageFormat::kPng8, 255.0}, {ImageFormat::kPng16, 65535.0}}) {
    ASSERT_TRUE(WriteImage(dir / "q.png", img, format).ok());
    auto png = ReadPngPixels(dir / "q.png");
    ASSERT_TRUE(png.ok()) << png.status();
    for (size_t i = 0; i < img.rgb.size(); ++i) {
      const float x = img.rgb[i];
      const long want = std::isnan(x) ? 0 : std::lround(std::clamp(double(x), 0.0, 1.0) * max);
      ASSERT_EQ(png->samples[i], uint16_t(want)) << "sample " << i << " = " << x << " of " << max;
    }
  }
}

TEST(AutoFrame, FitsTheSierpinskiTriangleWithItsMargin) {
  ChaosGameParams p = Sierpinski(1);
  p.frame.bounds = {{-10, -10, -10}, {10, 10, 10}};
  AutoFrameParams fit;
  fit.margin = 0.1;
  fit.trim = 0;
  auto box = FitBounds(p, fit, nullptr);
  ASSERT_TRUE(box.ok());
  for (int a = 0; a < 2; ++a) {
    EXPECT_NEAR(box->min[a], -0.1, 0.01);
    EXPECT_NEAR(box->max[a], 1.1, 0.01);
  }
  EXPECT_LT(box->max.z - box->min.z, 0.01);  // flat: a thin slab around z = 0
  EXPECT_GT(box->max.z, 0);
  EXPECT_LT(box->min.z, 0);
  auto again = FitBounds(p, fit, nullptr);
  EXPECT_EQ(again->min, box->min);
  EXPECT_EQ(again->max, box->max);
}

}  // namespace
}  // namespace nimbus
