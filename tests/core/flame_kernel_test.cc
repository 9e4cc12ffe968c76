// The batched flame kernels (core/chaos/flame_walk.h): the scalar kernel
// is bitwise PointMap::Apply; the AVX2 and AVX-512 kernels agree with it
// within the bound docs/chaos_game.md states; every kernel is reproducible
// and independent of the thread count.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "core/base/cpu_dispatch.h"
#include "core/chaos/chaos_game.h"
#include "core/chaos/flame_program.h"

namespace nimbus {
namespace {

// The SIMD kernels' error bound against the scalar kernel, in units of the
// last place of the larger of 1, |input| and |output| (docs/chaos_game.md).
constexpr double kUlpBound = 16;
constexpr int kLanes = 16;  // slots per test batch

std::vector<SimdLevel> VectorLevels() {
  std::vector<SimdLevel> levels;
  if (DetectSimd() >= SimdLevel::kAvx2) levels.push_back(SimdLevel::kAvx2);
  if (DetectSimd() >= SimdLevel::kAvx512) levels.push_back(SimdLevel::kAvx512);
  return levels;
}

PointMap OneTermMap(VariationKind kind) {
  PointMap m;
  m.pre = Affine3::Translate({0.1, -0.2, 0.05}) * Affine3::Rotate({1, 2, 3}, 25) *
          Affine3::Scale({0.9, 1.1, 0.8});
  m.variations = {{kind, 0.75, {}}};
  m.post = Affine3::Translate({0.0, 0.1, 0.0});
  return m;
}

// Lanes' points: spread over |coordinate| <= 3, plus the axis (rho = 0).
std::vector<Vec3> TestPoints(int n) {
  std::vector<Vec3> pts;
  Rng rng(5, 0);
  for (int i = 0; i < n; ++i)
    pts.push_back({rng.Uniform(-3, 3), rng.Uniform(-3, 3), rng.Uniform(-3, 3)});
  return pts;
}

// Applies `maps` to `pts` in batches of kLanes slots with one kernel; slot
// k uses map k % maps.size() and point i draws from its own stream (9, i).
std::vector<Vec3> RunKernel(const std::vector<PointMap>& maps, const std::vector<Vec3>& pts,
                            SimdLevel level) {
  const FlameProgram program(maps);
  const flame::ApplyMapsFn kernel = FlameKernel(level);
  std::vector<double> draws(std::max(program.draw_columns(), 1u) * flame::kSlots);
  std::vector<Vec3> out;
  for (size_t start = 0; start < pts.size(); start += kLanes) {
    flame::Batch b;
    b.draws = draws.data();
    b.count = kLanes;
    for (int k = 0; k < kLanes; ++k) {
      const Vec3 p = pts[(start + k) % pts.size()];
      b.x[k] = p.x, b.y[k] = p.y, b.z[k] = p.z;
      b.map[k] = int64_t(k % maps.size());
      Rng rng(9, start + k);
      program.Draw(uint32_t(b.map[k]), rng, draws.data(), k);
    }
    kernel(program.tables(), b);
    for (int k = 0; k < kLanes && start + k < pts.size(); ++k)
      out.push_back({b.x[k], b.y[k], b.z[k]});
  }
  return out;
}

double Ulps(double got, double want, double scale) {
  if (std::isnan(got) && std::isnan(want)) return 0;
  if (got == want) return 0;
  const double ulp = std::nextafter(scale, INFINITY) - scale;
  return std::fabs(got - want) / ulp;
}

TEST(FlameKernel, ScalarKernelIsBitwisePointMapApply) {
  const std::vector<Vec3> pts = TestPoints(160);
  for (VariationKind kind : AllVariations()) {
    SCOPED_TRACE(std::string(VariationName(kind)));
    const std::vector<PointMap> maps = {OneTermMap(kind), OneTermMap(VariationKind::kLinear)};
    const std::vector<Vec3> got = RunKernel(maps, pts, SimdLevel::kScalar);
    for (size_t i = 0; i < pts.size(); ++i) {
      // Lane i's draws come from Rng(9, i), as Apply draws them.
      Rng rng(9, i);
      const Vec3 want = maps[i % kLanes % 2].Apply(pts[i], rng);
      EXPECT_EQ(std::memcmp(&got[i], &want, sizeof(Vec3)), 0)
          << "point " << i << ": " << got[i].x << " " << want.x;
    }
  }
}

TEST(FlameKernel, VectorKernelsAgreeWithTheScalarKernelWithinTheBound) {
  if (VectorLevels().empty()) GTEST_SKIP() << "no AVX2 on this CPU";
  std::vector<Vec3> pts = TestPoints(4000);
  pts.push_back({0, 0, 0.5});  // the planar axis
  pts.push_back({0, 0, 0});
  for (VariationKind kind : AllVariations()) {
    SCOPED_TRACE(std::string(VariationName(kind)));
    const std::vector<PointMap> maps = {OneTermMap(kind)};
    const std::vector<Vec3> scalar = RunKernel(maps, pts, SimdLevel::kScalar);
    for (SimdLevel level : VectorLevels()) {
      SCOPED_TRACE(std::string(SimdName(level)));
      const std::vector<Vec3> got = RunKernel(maps, pts, level);
      double worst = 0;
      size_t checked = 0;
      for (size_t i = 0; i < pts.size(); ++i) {
        const Vec3 q = maps[0].pre.Apply(pts[i]);
        // tan near its poles turns one ulp into anything: popcorn is
        // compared where |tan 3x| and |tan 3y| stay below 10.
        if (kind == VariationKind::kPopcorn &&
            (std::fabs(std::tan(3 * q.x)) > 10 || std::fabs(std::tan(3 * q.y)) > 10))
          continue;
        ++checked;
        const Vec3 s = scalar[i], v = got[i];
        for (int a = 0; a < 3; ++a) {
          const double scale = std::max({1.0, Length(q), std::fabs(s[a])});
          worst = std::max(worst, Ulps(v[a], s[a], scale));
        }
      }
      RecordProperty(
          std::string(VariationName(kind)) + "_" + std::string(SimdName(level)) + "_ulps",
          absl::StrCat(worst));
      EXPECT_GT(checked, pts.size() / 2);
      EXPECT_LE(worst, kUlpBound);
    }
  }
}

TEST(FlameKernel, Avx2AndAvx512KernelsAgreeBitForBit) {
  if (DetectSimd() < SimdLevel::kAvx512) GTEST_SKIP() << "no AVX-512 on this CPU";
  const std::vector<Vec3> pts = TestPoints(2000);
  for (VariationKind kind : AllVariations()) {
    SCOPED_TRACE(std::string(VariationName(kind)));
    const std::vector<PointMap> maps = {OneTermMap(kind), OneTermMap(VariationKind::kJulia)};
    const std::vector<Vec3> a = RunKernel(maps, pts, SimdLevel::kAvx2);
    const std::vector<Vec3> b = RunKernel(maps, pts, SimdLevel::kAvx512);
    ASSERT_EQ(a.size(), b.size());
    EXPECT_EQ(std::memcmp(a.data(), b.data(), a.size() * sizeof(Vec3)), 0);
  }
}

// A coloured flame with post and final transforms and random variations.
ChaosGameParams SmallFlame() {
  using K = VariationKind;
  ChaosGameParams p;
  auto map = [](Affine3 pre, std::vector<VariationTerm> terms, double color) {
    PointMap m;
    m.pre = pre;
    m.variations = std::move(terms);
    m.color = color;
    return m;
  };
  p.ifs.maps = {
      map(Affine3::Rotate({0, 0, 1}, 30) * Affine3::Scale({0.6, 0.6, 0.6}),
          {{K::kSwirl, 0.6, {}}, {K::kSpherical, 0.4, {}}}, 0.1),
      map(Affine3::Translate({-0.4, 0.5, 0}), {{K::kJulia, 0.8, {}}, {K::kSinusoidal, 0.2, {}}},
          0.5),
      map(Affine3::Translate({0, -0.3, 0.1}) * Affine3::Scale({0.5, 0.5, 0.5}),
          {{K::kBubble, 0.5, {}}, {K::kPolar, 0.4, {}}, {K::kBlur, 0.1, {}}}, 0.9),
  };
  p.ifs.maps[1].post = Affine3::Rotate({1, 0, 0}, 20);
  p.ifs.probabilities = {0.4, 0.35, 0.25};
  p.ifs.final_map = map(Affine3::Identity(), {{K::kLinear, 0.95, {}}, {K::kNoise, 0.05, {}}}, 0);
  p.frame = {{64, 64, 64}, {{-2, -2, -2}, {2, 2, 2}}};
  p.iterations = ChaosGame::kChunkIterations * 3 + 1001;
  p.warmup = 40;
  p.seed = 11;
  p.color = {ColorMode::kMap, 0.5};
  return p;
}

struct FlameRun {
  std::vector<uint32_t> counts;
  std::vector<uint64_t> colours;
  ChaosGameStats stats;
};

FlameRun RunFlame(ChaosGameParams p, SimdLevel level, int threads) {
  p.simd = level;
  auto game = ChaosGame::Create(p, threads);
  EXPECT_TRUE(game.ok()) << game.status();
  EXPECT_TRUE((*game)->Run(nullptr).ok());
  FlameRun r;
  r.stats = (*game)->stats();
  const CountGrid g = (*game)->TakeCounts();
  const Int3 res = g.resolution();
  for (int x = 0; x < res.x; ++x)
    for (int y = 0; y < res.y; ++y)
      for (int z = 0; z < res.z; ++z) {
        r.counts.push_back(g.Get(x, y, z));
        r.colours.push_back(g.GetColorSum(x, y, z));
      }
  return r;
}

TEST(FlameKernel, EveryKernelIsReproducibleAndIndependentOfThreads) {
  std::vector<SimdLevel> levels = {SimdLevel::kScalar};
  for (SimdLevel l : VectorLevels()) levels.push_back(l);
  const ChaosGameParams p = SmallFlame();
  for (SimdLevel level : levels) {
    SCOPED_TRACE(std::string(SimdName(level)));
    const FlameRun one = RunFlame(p, level, 1);
    const FlameRun two = RunFlame(p, level, 2);
    const FlameRun again = RunFlame(p, level, 2);
    EXPECT_EQ(one.counts, two.counts);
    EXPECT_EQ(one.colours, two.colours);
    EXPECT_EQ(two.counts, again.counts);
    EXPECT_EQ(two.colours, again.colours);
    EXPECT_EQ(one.stats.outside, two.stats.outside);
    EXPECT_EQ(one.stats.reseeded, two.stats.reseeded);
  }
}

TEST(FlameKernel, VectorKernelsDrawTheSameDensityAsTheScalarKernel) {
  if (VectorLevels().empty()) GTEST_SKIP() << "no AVX2 on this CPU";
  const ChaosGameParams p = SmallFlame();
  const FlameRun scalar = RunFlame(p, SimdLevel::kScalar, 2);
  // 8^3 cells of 8^3 voxels: the walks diverge after a few ulps, so only
  // the distribution is shared.
  auto coarse = [](const FlameRun& r) {
    std::vector<double> c(512, 0.0);
    double total = 0;
    for (size_t i = 0; i < r.counts.size(); ++i) {
      const size_t x = i / 4096, y = i / 64 % 64, z = i % 64;
      c[(x / 8 * 8 + y / 8) * 8 + z / 8] += r.counts[i];
      total += r.counts[i];
    }
    for (double& v : c) v /= total;
    return c;
  };
  const std::vector<double> want = coarse(scalar);
  for (SimdLevel level : VectorLevels()) {
    SCOPED_TRACE(std::string(SimdName(level)));
    const std::vector<double> got = coarse(RunFlame(p, level, 2));
    double l1 = 0;
    for (size_t i = 0; i < got.size(); ++i) l1 += std::fabs(got[i] - want[i]);
    RecordProperty("l1_" + std::string(SimdName(level)), absl::StrCat(l1));
    EXPECT_LT(l1, 0.02);
  }
}

}  // namespace
}  // namespace nimbus
