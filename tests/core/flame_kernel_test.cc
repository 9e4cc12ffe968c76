// The flame kernels (core/chaos/flame_walk.h): the scalar kernel is
// bitwise the step docs/chaos_game.md describes; the AVX2 and AVX-512 kernels agree with it
// within the bound docs/chaos_game.md states; every kernel is reproducible
// and independent of the thread count.
#include <gtest/gtest.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <memory>
#include <optional>
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

struct KernelRun {
  std::vector<Vec3> points;
  std::vector<uint32_t> maps;        // the map each point took
  std::vector<double> addr, colour;  // each walker's colour state after it
};

// One round of one kernel on each point, in blocks of kMaxWalkers walkers
// with equally likely maps; point i's walker draws from stream (9, i).
KernelRun RunKernel(const std::vector<PointMap>& maps, const std::vector<Vec3>& pts,
                    SimdLevel level, std::vector<double> weights = {}, int color_mode = 0) {
  if (weights.empty()) weights.assign(maps.size(), 1.0);
  const AliasTable table(weights);
  const FlameProgram program(maps, std::nullopt, table, color_mode, 0.5);
  const flame::RoundFn kernel = FlameKernel(level);
  constexpr int kN = flame::kMaxWalkers;
  std::vector<uint64_t> words(size_t(program.program().words) * kN);
  std::vector<uint32_t> group(maps.size() + 1);
  auto b = std::make_unique<flame::Walkers>();
  b->words = words.data();
  b->group = group.data();
  KernelRun run;
  for (size_t start = 0; start < pts.size(); start += kN) {
    for (int k = 0; k < kN; ++k) {
      const Vec3 p = pts[(start + k) % pts.size()];
      b->x[k] = p.x, b->y[k] = p.y, b->z[k] = p.z;
      const Rng rng(9, start + k);
      b->s0[k] = rng.state(0), b->s1[k] = rng.state(1);
      b->s2[k] = rng.state(2), b->s3[k] = rng.state(3);
      b->addr[k] = double(k) / kN, b->col[k] = 1 - double(k) / kN;
    }
    kernel(program.program(), *b, kN);
    for (int k = 0; k < kN && start + k < pts.size(); ++k) {
      run.points.push_back({b->x[k], b->y[k], b->z[k]});
      run.maps.push_back(b->map[k]);
      run.addr.push_back(b->addr[k]);
      run.colour.push_back(b->col[k]);
    }
  }
  return run;
}

// What the engine's contract says walker i's step computes: map from word
// 0 of its stream, then pre, the terms on words 1.., post.
Vec3 ExpectedStep(const std::vector<PointMap>& maps, Vec3 p, uint64_t stream, uint32_t* map_out) {
  const AliasTable table(std::vector<double>(maps.size(), 1.0));
  Rng rng(9, stream);
  std::vector<uint64_t> words(16);
  for (uint64_t& w : words) w = rng.Next();
  const PointMap& m = maps[table.Sample(words[0])];
  *map_out = table.Sample(words[0]);
  const Vec3 q = m.pre.Apply(p);
  Vec3 sum;
  const uint64_t* next = words.data() + 1;
  for (const VariationTerm& t : m.variations) {
    sum = sum + t.weight * EvaluateVariation(t, q, m.pre, next);
    next += VariationWords(t.kind);
  }
  const Vec3 s = m.variations.empty() ? q : sum;
  return m.post ? m.post->Apply(s) : s;
}

double Ulps(double got, double want, double scale) {
  if (std::isnan(got) && std::isnan(want)) return 0;
  if (got == want) return 0;
  const double ulp = std::nextafter(scale, INFINITY) - scale;
  return std::fabs(got - want) / ulp;
}

TEST(FlameKernel, ScalarKernelIsBitwiseTheDocumentedStep) {
  const std::vector<Vec3> pts = TestPoints(160);
  for (VariationKind kind : AllVariations()) {
    SCOPED_TRACE(std::string(VariationName(kind)));
    const std::vector<PointMap> maps = {OneTermMap(kind), OneTermMap(VariationKind::kLinear),
                                        OneTermMap(VariationKind::kBlur)};
    const KernelRun got = RunKernel(maps, pts, SimdLevel::kScalar);
    for (size_t i = 0; i < pts.size(); ++i) {
      uint32_t map = 0;
      const Vec3 want = ExpectedStep(maps, pts[i], i, &map);
      EXPECT_EQ(got.maps[i], map);
      EXPECT_EQ(std::memcmp(&got.points[i], &want, sizeof(Vec3)), 0)
          << "point " << i << ": " << got.points[i].x << " " << want.x;
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
    const std::vector<Vec3> scalar = RunKernel(maps, pts, SimdLevel::kScalar).points;
    for (SimdLevel level : VectorLevels()) {
      SCOPED_TRACE(std::string(SimdName(level)));
      const std::vector<Vec3> got = RunKernel(maps, pts, level).points;
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
    const std::vector<Vec3> a = RunKernel(maps, pts, SimdLevel::kAvx2).points;
    const std::vector<Vec3> b = RunKernel(maps, pts, SimdLevel::kAvx512).points;
    ASSERT_EQ(a.size(), b.size());
    EXPECT_EQ(std::memcmp(a.data(), b.data(), a.size() * sizeof(Vec3)), 0);
  }
}

TEST(FlameKernel, VectorKernelsPickTheSameMapsAndAgreeWithManyMaps) {
  // Eleven maps of unequal weight: the vector alias sampling against the
  // scalar one, and more maps than the AVX-512 kernel sorts by compress.
  std::vector<PointMap> maps;
  std::vector<double> weights;
  for (int i = 0; i < 11; ++i) {
    maps.push_back(OneTermMap(AllVariations()[size_t(i * 2) % AllVariations().size()]));
    weights.push_back(1.0 + i * i);
  }
  const std::vector<Vec3> pts = TestPoints(1000);
  const KernelRun scalar = RunKernel(maps, pts, SimdLevel::kScalar, weights);
  std::vector<KernelRun> vector_runs;
  for (SimdLevel level : VectorLevels()) {
    SCOPED_TRACE(std::string(SimdName(level)));
    vector_runs.push_back(RunKernel(maps, pts, level, weights));
    EXPECT_EQ(vector_runs.back().maps, scalar.maps);
  }
  // Every map is taken, the heavier ones more often.
  std::vector<int> taken(maps.size(), 0);
  for (uint32_t m : scalar.maps) ++taken[m];
  for (size_t m = 0; m < maps.size(); ++m) EXPECT_GT(taken[m], 0) << m;
  EXPECT_GT(taken[10], taken[1]);
  if (vector_runs.size() == 2) {
    EXPECT_EQ(std::memcmp(vector_runs[0].points.data(), vector_runs[1].points.data(),
                          pts.size() * sizeof(Vec3)),
              0);
  }
}

// The AVX-512 kernel stages each map's walkers into runs (up to
// flame::kStageMaps maps and flame::kStageWords words per map) and goes by
// walker index otherwise; AVX2 always goes by index. Lopsided weights give
// empty runs, one-walker runs and runs of whole registers.
TEST(FlameKernel, Avx512StagedRunsAgreeWithTheIndexedKernelBitForBit) {
  if (DetectSimd() < SimdLevel::kAvx512) GTEST_SKIP() << "no AVX-512 on this CPU";
  const std::vector<Vec3> pts = TestPoints(3000);
  for (int count : {1, 2, 3, 5, 8, 9}) {
    for (double heavy : {1.0, 40.0}) {
      SCOPED_TRACE(absl::StrCat(count, " maps, heavy ", heavy));
      std::vector<PointMap> maps;
      std::vector<double> weights;
      for (int i = 0; i < count; ++i) {
        const VariationKind kind = AllVariations()[size_t(i * 5 + 3) % AllVariations().size()];
        maps.push_back(OneTermMap(kind));
        maps.back().variations.push_back({VariationKind::kJulia, 0.25, {}});
        weights.push_back(i == 0 ? heavy : 1.0);
      }
      const KernelRun a = RunKernel(maps, pts, SimdLevel::kAvx2, weights);
      const KernelRun b = RunKernel(maps, pts, SimdLevel::kAvx512, weights);
      EXPECT_EQ(a.maps, b.maps);
      EXPECT_EQ(std::memcmp(a.points.data(), b.points.data(), pts.size() * sizeof(Vec3)), 0);
    }
  }
  // More random words than the staging holds: the indexed pass.
  PointMap many = OneTermMap(VariationKind::kBlur);
  many.variations.push_back({VariationKind::kNoise, 0.5, {}});
  const std::vector<PointMap> maps = {many, OneTermMap(VariationKind::kSwirl)};
  const KernelRun a = RunKernel(maps, pts, SimdLevel::kAvx2);
  const KernelRun b = RunKernel(maps, pts, SimdLevel::kAvx512);
  EXPECT_EQ(std::memcmp(a.points.data(), b.points.data(), pts.size() * sizeof(Vec3)), 0);
}

// The walkers' colours, by map and by address, with the alias table's
// columns and aliases both taken: every level recolours as the scalar
// kernel does, bit for bit (AVX-512 draws, picks and recolours in one
// pass, its tables in registers up to eight maps and gathered above).
TEST(FlameKernel, VectorKernelsRecolourAsTheScalarKernelBitForBit) {
  const std::vector<Vec3> pts = TestPoints(1000);
  for (int count : {1, 3, 8, 9}) {
    for (int mode : {1, 2}) {
      SCOPED_TRACE(absl::StrCat(count, " maps, colour mode ", mode));
      std::vector<PointMap> maps;
      std::vector<double> weights;
      for (int i = 0; i < count; ++i) {
        maps.push_back(OneTermMap(VariationKind::kSwirl));
        maps.back().color = 0.1 + 0.8 * i / count;
        weights.push_back(1.0 + i * i);
      }
      const KernelRun scalar = RunKernel(maps, pts, SimdLevel::kScalar, weights, mode);
      for (SimdLevel level : VectorLevels()) {
        SCOPED_TRACE(std::string(SimdName(level)));
        const KernelRun v = RunKernel(maps, pts, level, weights, mode);
        EXPECT_EQ(v.maps, scalar.maps);
        EXPECT_EQ(std::memcmp(v.addr.data(), scalar.addr.data(), pts.size() * sizeof(double)), 0);
        EXPECT_EQ(
            std::memcmp(v.colour.data(), scalar.colour.data(), pts.size() * sizeof(double)), 0);
      }
    }
  }
}

// A 2D flame's map: rows x and y without z, z's row zero, no post.
PointMap FlatMap(VariationKind kind, double weight, double tx) {
  PointMap m;
  m.pre.m = {{{0.7, 0.25, 0, tx}, {-0.3, 0.6, 0, 0.2}, {0, 0, 0, 0}}};
  m.variations = {{kind, weight, {}}, {VariationKind::kJulia, -0.3, {}}};
  return m;
}

// Which programs are planar: any z dependence, z row, post-affine, random
// direction or final transform, or a -0 constant in x or y, rules it out.
TEST(FlameKernel, PlanarProgramsAreThoseThatKeepZAtPlusZero) {
  const AliasTable one(std::vector<double>{1.0});
  auto planar = [&](const PointMap& m, bool with_final = false) {
    const std::optional<PointMap> final_map =
        with_final ? std::optional<PointMap>(FlatMap(VariationKind::kLinear, 1, 0)) : std::nullopt;
    return FlameProgram({m}, final_map, one, 0, 0.5).program().planar;
  };
  for (VariationKind kind : AllVariations()) {
    SCOPED_TRACE(std::string(VariationName(kind)));
    const bool random_z = kind == VariationKind::kBlur || kind == VariationKind::kNoise;
    EXPECT_EQ(planar(FlatMap(kind, 1, 0.1)), !random_z);
  }
  const PointMap flat = FlatMap(VariationKind::kSwirl, 1, 0.1);
  EXPECT_FALSE(planar(flat, /*with_final=*/true));
  PointMap m = flat;
  m.pre.m[0][2] = 0.1;  // x depends on z
  EXPECT_FALSE(planar(m));
  m = flat, m.pre.m[2][3] = 0.5;  // the plane z = 0.5
  EXPECT_FALSE(planar(m));
  m = flat, m.pre.m[2][3] = -0.0;  // z = -0 when x and y are -0
  EXPECT_FALSE(planar(m));
  m = flat, m.pre.m[1][3] = -0.0;  // y's zero sign could follow z's
  EXPECT_FALSE(planar(m));
  m = flat, m.pre.m[0][2] = -0.0;  // a zero coefficient of either sign is fine
  EXPECT_TRUE(planar(m));
  m = flat, m.post = Affine3::Identity();
  EXPECT_FALSE(planar(m));
}

// Planar programs' staged runs leave z out (AVX-512); AVX2 moves and
// computes it. From any finite start (z too: a restarted walker starts
// anywhere in the bounds), on the axis, far out and on signed zeros, both
// give the same x and y bit for bit and z = +0, for every variation that
// keeps a flame planar; non-finite walkers stay non-finite (they restart).
TEST(FlameKernel, Avx512PlanarRunsAgreeWithTheIndexedKernelBitForBit) {
  if (DetectSimd() < SimdLevel::kAvx512) GTEST_SKIP() << "no AVX-512 on this CPU";
  std::vector<Vec3> pts = TestPoints(3000);
  const double big = 1e200, inf = INFINITY;
  pts.insert(pts.end(), {{0, 0, 0},
                         {-0.0, -0.0, -0.0},
                         {0, 0, -0.3},
                         {big, -big, 0.2},
                         {-0.1 / 0.7 * 0.2, 0.2, 0},
                         {inf, 0, 0},
                         {NAN, 1, 0},
                         {0.5, 1e-300, -0.0}});
  for (VariationKind kind : AllVariations()) {
    if (kind == VariationKind::kBlur || kind == VariationKind::kNoise) continue;
    SCOPED_TRACE(std::string(VariationName(kind)));
    const std::vector<PointMap> maps = {FlatMap(kind, 0.8, 0.1), FlatMap(kind, -0.5, 0),
                                        FlatMap(VariationKind::kSpherical, 1, -0.2)};
    const AliasTable table(std::vector<double>(maps.size(), 1.0));
    ASSERT_TRUE(FlameProgram(maps, std::nullopt, table, 0, 0.5).program().planar);
    const KernelRun a = RunKernel(maps, pts, SimdLevel::kAvx2);
    const KernelRun b = RunKernel(maps, pts, SimdLevel::kAvx512);
    EXPECT_EQ(a.maps, b.maps);
    for (size_t i = 0; i < pts.size(); ++i) {
      const Vec3 &p = a.points[i], &q = b.points[i];
      if (!std::isfinite(p.x) || !std::isfinite(p.y)) {
        EXPECT_FALSE(std::isfinite(q.x) && std::isfinite(q.y)) << i;
        continue;
      }
      EXPECT_EQ(std::memcmp(&p.x, &q.x, sizeof(double)), 0) << i;
      EXPECT_EQ(std::memcmp(&p.y, &q.y, sizeof(double)), 0) << i;
      EXPECT_EQ(std::bit_cast<uint64_t>(p.z), 0u) << i;  // computed: +0
      EXPECT_EQ(std::bit_cast<uint64_t>(q.z), 0u) << i;  // stored: +0
    }
  }
}

// A planar map (no z row) keeps z = +0, and sinusoidal then skips sin z:
// sin(+-0) = +-0 in the C library and in SLEEF, so every kernel's z is
// the scalar kernel's, bit for bit.
TEST(FlameKernel, SinusoidalOfAFlatPointKeepsZBitForBit) {
  PointMap flat;
  flat.pre.m = {{{0.7, 0.2, 0, -0.4}, {-0.2, 0.7, 0, 0.5}, {0, 0, 0, 0}}};
  flat.variations = {{VariationKind::kSinusoidal, 1.0, {}}};
  std::vector<Vec3> pts = TestPoints(500);
  for (Vec3& p : pts) p.z = 0;
  const KernelRun scalar = RunKernel({flat}, pts, SimdLevel::kScalar);
  for (SimdLevel level : VectorLevels()) {
    SCOPED_TRACE(std::string(SimdName(level)));
    const KernelRun got = RunKernel({flat}, pts, level);
    for (size_t i = 0; i < pts.size(); ++i) {
      EXPECT_EQ(std::memcmp(&got.points[i].z, &scalar.points[i].z, sizeof(double)), 0) << i;
      EXPECT_FALSE(std::signbit(got.points[i].z)) << i;
      EXPECT_EQ(got.points[i].z, 0.0) << i;
    }
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

TEST(FlameKernel, Avx2AndAvx512EnginesCountTheSame) {
  if (DetectSimd() < SimdLevel::kAvx512) GTEST_SKIP() << "no AVX-512 on this CPU";
  ChaosGameParams p = SmallFlame();
  p.iterations = ChaosGame::kChunkIterations + 333;
  const FlameRun a = RunFlame(p, SimdLevel::kAvx2, 2);
  const FlameRun b = RunFlame(p, SimdLevel::kAvx512, 2);
  EXPECT_EQ(a.counts, b.counts);
  EXPECT_EQ(a.colours, b.colours);
  EXPECT_EQ(a.stats.outside, b.stats.outside);
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
