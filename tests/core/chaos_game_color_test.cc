// Colour, final transforms, reproducibility and memory bounds of the chaos
// game (issue 3).
#include <gtest/gtest.h>

#include <array>
#include <bit>
#include <cmath>
#include <cstring>
#include <vector>

#include "tests/support/attractors.h"
#include "core/chaos/chaos_game.h"
#include "core/chaos/image_plane.h"
#include "core/chaos/tile_bins.h"
#include "core/base/cpu_dispatch.h"
#include "core/base/random.h"
#include "core/grid/palette.h"
#include "core/grid/sine_batch.h"
#include "core/base/sha256.h"
#include "core/io/vdb_io.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

// A volume-filling IFS: eight half-size copies at the octants of [-1, 1]^3,
// each slightly rotated so the maps are not axis-aligned.
ChaosGameParams OctantCloud(uint64_t iterations, int resolution, double degrees = 7.0) {
  ChaosGameParams p;
  for (int i = 0; i < 8; ++i) {
    PointMap m;
    const Vec3 o{(i & 1) ? 0.5 : -0.5, (i & 2) ? 0.5 : -0.5, (i & 4) ? 0.5 : -0.5};
    m.pre = Affine3::Translate(o) * Affine3::Rotate({1, 1, 1}, degrees * i) *
            Affine3::Scale({0.5, 0.5, 0.5});
    m.color = i / 7.0;
    p.ifs.maps.push_back(m);
  }
  p.ifs.probabilities.assign(8, 1.0 / 8);
  p.frame.resolution = {resolution, resolution, resolution};
  p.frame.bounds = {{-1.2, -1.2, -1.2}, {1.2, 1.2, 1.2}};
  p.iterations = iterations;
  p.seed = 11;
  return p;
}

CountGrid RunGame(const ChaosGameParams& params, int threads, ChaosGameStats* stats = nullptr) {
  auto game = ChaosGame::Create(params, threads);
  EXPECT_TRUE(game.ok()) << game.status();
  const absl::Status run = (*game)->Run(nullptr);
  EXPECT_TRUE(run.ok()) << run;
  if (stats) *stats = (*game)->stats();
  return (*game)->TakeCounts();
}

void ExpectSameGrids(const CountGrid& a, const CountGrid& b) {
  ASSERT_EQ(a.AllocatedTiles(), b.AllocatedTiles());
  const Int3 r = a.resolution();
  for (int x = 0; x < r.x; ++x)
    for (int y = 0; y < r.y; ++y)
      for (int z = 0; z < r.z; ++z) {
        ASSERT_EQ(a.Get(x, y, z), b.Get(x, y, z)) << x << "," << y << "," << z;
        ASSERT_EQ(a.GetColorSum(x, y, z), b.GetColorSum(x, y, z)) << x << "," << y << "," << z;
      }
}

TEST(ChaosGameColor, SinePaletteMatchesTheSeedFormula) {
  const Palette p;
  for (double t : {0.0, 0.1, 0.37, 0.5, 0.99, 1.0}) {
    const double a = 2 * M_PI * t;
    const Vec3 c = p.Eval(t);
    EXPECT_DOUBLE_EQ(c.x, 0.4 + 0.25 * std::sin(0.5 + a));
    EXPECT_DOUBLE_EQ(c.y, 0.6 + 0.25 * std::sin(0.9 + a));
    EXPECT_DOUBLE_EQ(c.z, 0.7 + 0.25 * std::sin(1.3 + a));
  }
}

// SinMany's vector sines stay within 2 ulp of the C library's (each is
// within 1 ulp of the truth), the bound Palette::EvalFloats relies on.
TEST(ChaosGameColor, VectorSinesStayWithinTwoUlpOfTheCLibrary) {
  Rng rng(7, 0);
  std::vector<double> x(100003);
  for (double& v : x) v = 0.5 + 2 * M_PI * rng.Uniform() + rng.Uniform();
  x[0] = 0, x[1] = M_PI, x[2] = 1e-300;
  for (SimdLevel level : {SimdLevel::kScalar, SimdLevel::kAvx2, SimdLevel::kAvx512}) {
    if (level > DetectSimd()) continue;
    SCOPED_TRACE(SimdName(level));
    std::vector<double> s(x.size());
    SinManyAt(level, x.data(), s.data(), x.size());
    for (size_t k = 0; k < x.size(); ++k) {
      const double want = std::sin(x[k]);
      ASSERT_LE(std::fabs(s[k] - want), 2 * (std::nextafter(std::fabs(want), 2.0) - std::fabs(want)))
          << "x = " << x[k];
    }
  }
}

// t values whose sine-palette channel `c` lies within a few ulp of a
// float rounding boundary, where the batched palette must fall back to
// the C library's sine: the boundary's sine solved for t.
std::vector<double> NearRoundingBoundaries(int c) {
  constexpr double kBase[3] = {0.4, 0.6, 0.7}, kPhase[3] = {0.5, 0.9, 1.3};
  std::vector<double> ts;
  for (float f = float(kBase[c] - 0.2); f < float(kBase[c] + 0.2); f += 0.01f) {
    const double mid = (double(f) + double(std::nextafter(f, 2.0f))) / 2;
    const double a = std::asin((mid - kBase[c]) / 0.25) - kPhase[c];
    for (double t : {a / (2 * M_PI), a / (2 * M_PI) + 1})
      if (t >= 0 && t <= 1) ts.push_back(t);
  }
  return ts;
}

// EvalFloats is float(Eval) bit for bit: on random coordinates, on the
// quantised ones a voxel's colour sum gives, out of range, and near the
// float rounding boundaries where the vector sine is not trusted.
TEST(ChaosGameColor, BatchedPaletteRoundsExactlyAsEval) {
  std::vector<double> t;
  Rng rng(11, 0);
  for (int i = 0; i < 300000; ++i) t.push_back(rng.Uniform());
  for (uint64_t n = 1; n < 50; ++n)
    for (uint64_t sum = 0; sum <= 65535 * n; sum += 997) t.push_back(double(sum) / 65535.0 / double(n));
  for (double v : {0.0, 1.0, -0.5, 1.5, std::nan("")}) t.push_back(v);
  int near = 0;
  for (int c = 0; c < 3; ++c)
    for (double v : NearRoundingBoundaries(c)) t.push_back(v), ++near;
  ASSERT_GT(near, 50);
  for (const Palette& p :
       {Palette(), Palette({{0.2, {1, 0, 0}}, {0.6, {0, 1, 0}}, {1.0, {0, 0, 1}}})}) {
    std::vector<std::array<float, 3>> got(t.size());
    p.EvalFloats(t.data(), t.size(), got.data());
    for (size_t k = 0; k < t.size(); ++k) {
      const Vec3 want = p.Eval(t[k]);
      for (int c = 0; c < 3; ++c)
        ASSERT_EQ(std::bit_cast<uint32_t>(got[k][size_t(c)]), std::bit_cast<uint32_t>(float(want[c])))
            << "t = " << t[k] << ", channel " << c;
    }
  }
}

// The batched palette's guard: a value it trusts rounds to the same float
// anywhere within 2^-50 of it; a value at a rounding boundary, or within
// a few ulp of one, is not trusted.
TEST(ChaosGameColor, RoundingGuardTrustsOnlyValuesFarFromABoundary) {
  using palette_internal::RoundsSafely;
  Rng rng(13, 0);
  int trusted = 0;
  for (int i = 0; i < 200000; ++i) {
    const double v = 0.1 + 0.85 * rng.Uniform();
    if (!RoundsSafely(v)) continue;
    ++trusted;
    ASSERT_EQ(float(v + 0x1.0p-50), float(v)) << v;
    ASSERT_EQ(float(v - 0x1.0p-50), float(v)) << v;
  }
  EXPECT_GT(trusted, 199990);
  for (float f : {0.15f, 0.3f, 0.5f, 0.77f, 0.94f}) {
    const double mid = (double(f) + double(std::nextafter(f, 2.0f))) / 2;
    EXPECT_FALSE(RoundsSafely(mid)) << f;
    EXPECT_FALSE(RoundsSafely(std::nextafter(mid, 0.0))) << f;
    EXPECT_FALSE(RoundsSafely(mid + 0x1.0p-51)) << f;
    EXPECT_TRUE(RoundsSafely(double(f))) << f;
  }
}

TEST(ChaosGameColor, GradientStopsInterpolateAndClamp) {
  const Palette p({{0.2, {1, 0, 0}}, {0.6, {0, 1, 0}}, {1.0, {0, 0, 1}}});
  auto near = [](Vec3 a, Vec3 b) { return Length(a - b) < 1e-12; };
  EXPECT_TRUE(near(p.Eval(0.0), {1, 0, 0}));
  EXPECT_TRUE(near(p.Eval(0.4), {0.5, 0.5, 0}));
  EXPECT_TRUE(near(p.Eval(0.8), {0, 0.5, 0.5}));
  EXPECT_TRUE(near(p.Eval(1.0), {0, 0, 1}));
  EXPECT_EQ(p.MinColor(), (Vec3{0, 0, 0}));
  EXPECT_EQ(p.MaxColor(), (Vec3{1, 1, 1}));
}

TEST(ChaosGameColor, IdentityFinalTransformMatchesNoneBitwise) {
  ChaosGameParams params = OctantCloud(3'000'000, 48);
  params.color.mode = ColorMode::kAddress;
  const CountGrid none = RunGame(params, 2);
  params.ifs.final_map = PointMap{};  // identity pre, no variations
  const CountGrid identity = RunGame(params, 2);
  ExpectSameGrids(none, identity);
  // An arcs transform with all-zero parameters is the identity too.
  params.ifs.final_map.reset();
  params.ifs.arcs = ArcsTransform{};
  ExpectSameGrids(none, RunGame(params, 2));
}

TEST(ChaosGameColor, FinalTransformOnlyMovesPlottedPoints) {
  // A translation by +1 in x as final map shifts the whole density by the
  // matching number of voxels but leaves the walk (and total) alone.
  ChaosGameParams params = OctantCloud(2'000'000, 32);
  params.frame.bounds = {{-1.5, -1.5, -1.5}, {3.3, 1.5, 1.5}};  // voxel 0.15
  params.frame.resolution = {32, 20, 20};
  const CountGrid plain = RunGame(params, 1);
  PointMap shift;
  shift.pre = Affine3::Translate({0.15 * 4, 0, 0});
  params.ifs.final_map = shift;
  const CountGrid moved = RunGame(params, 1);
  EXPECT_EQ(plain.Total(), moved.Total());
  int differing = 0;
  for (int x = 0; x + 4 < 32; ++x)
    for (int y = 0; y < 20; ++y)
      for (int z = 0; z < 20; ++z) differing += plain.Get(x, y, z) != moved.Get(x + 4, y, z);
  // Rounding at voxel boundaries may move a handful of points.
  EXPECT_LT(differing, 20);
}

TEST(ChaosGameColor, ArcsRotateAboutZ) {
  const ArcsTransform arcs{0.5, 0.2, 0.3};
  const Vec3 p{1.0, 0.5, -0.25};
  const Vec3 q = arcs.Apply(p, 7);
  const double theta = 0.5 * 1.0 + 0.2 * std::sin(0.3 * 7);
  EXPECT_NEAR(q.x, std::cos(theta) * 1.0 - std::sin(theta) * 0.5, 1e-15);
  EXPECT_NEAR(q.y, std::sin(theta) * 1.0 + std::cos(theta) * 0.5, 1e-15);
  EXPECT_EQ(q.z, -0.25);
  EXPECT_NEAR(Length(q - Vec3{0, 0, q.z}), Length(p - Vec3{0, 0, p.z}), 1e-15);
}

TEST(ChaosGameColor, OneAndTwoThreadsGiveIdenticalCountsAndColour) {
  for (ColorMode mode : {ColorMode::kAddress, ColorMode::kMap}) {
    ChaosGameParams params = OctantCloud(5'000'000, 40);
    params.color.mode = mode;
    params.ifs.arcs = ArcsTransform{0.3, 0.05, 0.01};
    ExpectSameGrids(RunGame(params, 1), RunGame(params, 2));
  }
}

TEST(ChaosGameColor, WholeVdbIdenticalForOneAndTwoThreads) {
  testing::TempDir dir;
  ChaosGameParams params = OctantCloud(4'000'000, 40);
  params.color.mode = ColorMode::kAddress;
  DensityOptions opt;
  opt.mapping = DensityMapping::kSqrt;
  opt.color = true;
  opt.address_grid = true;
  opt.raw_counts = RawCounts::kFloat;
  std::vector<std::filesystem::path> files;
  for (int threads : {1, 2}) {
    files.push_back(dir / ("t" + std::to_string(threads) + ".vdb"));
    ASSERT_TRUE(
        WriteDensityVdb(files.back(), RunGame(params, threads), params.frame, opt, {}).ok());
  }
  for (const char* name : {"density", "address", "counts"}) {
    auto a = ReadVdbFile(files[0], name), b = ReadVdbFile(files[1], name);
    ASSERT_TRUE(a.ok() && b.ok()) << name;
    ASSERT_EQ(a->values.size(), b->values.size());
    EXPECT_EQ(0, std::memcmp(a->values.data(), b->values.data(), a->values.size() * 4)) << name;
    EXPECT_EQ(a->metadata, b->metadata) << name;
  }
  auto ca = ReadVec3VdbFile(files[0]), cb = ReadVec3VdbFile(files[1]);
  ASSERT_TRUE(ca.ok() && cb.ok());
  EXPECT_EQ(ca->values, cb->values);
  EXPECT_EQ(ca->active, cb->active);
  // And the files themselves, byte for byte (the UUID is content-derived).
  EXPECT_EQ(*Sha256File(files[0]), *Sha256File(files[1]));
}

TEST(ChaosGameColor, CdLiesInsideThePaletteRange) {
  testing::TempDir dir;
  ChaosGameParams params = OctantCloud(2'000'000, 32);
  params.color.mode = ColorMode::kAddress;
  const CountGrid counts = RunGame(params, 2);
  for (const Palette& palette :
       {Palette(), Palette({{0, {0.1, 0.2, 0.3}}, {0.5, {0.9, 0.1, 0.5}}, {1, {0.3, 0.8, 0.2}}})}) {
    DensityOptions opt;
    opt.color = true;
    opt.palette = palette;
    const auto path = dir / "cd.vdb";
    ASSERT_TRUE(WriteDensityVdb(path, counts, params.frame, opt, {}).ok());
    auto cd = ReadVec3VdbFile(path);
    ASSERT_TRUE(cd.ok()) << cd.status();
    auto density = ReadVdbFile(path);
    ASSERT_TRUE(density.ok());
    const Vec3 lo = palette.MinColor(), hi = palette.MaxColor();
    size_t active = 0;
    std::vector<double> seen;
    for (size_t i = 0; i < cd->values.size(); ++i) {
      // Cd is active exactly where the density is.
      ASSERT_EQ(cd->active[i], density->values[i] > 0);
      if (!cd->active[i]) continue;
      ++active;
      for (int a = 0; a < 3; ++a) {
        ASSERT_GE(cd->values[i][a], lo[a] - 1e-6);
        ASSERT_LE(cd->values[i][a], hi[a] + 1e-6);
      }
      seen.push_back(cd->values[i].x);
    }
    ASSERT_GT(active, 1000u);
    // Addresses spread over the palette: the red channel is not constant.
    const auto [mn, mx] = std::minmax_element(seen.begin(), seen.end());
    EXPECT_GT(*mx - *mn, 0.1);
  }
}

TEST(ChaosGameColor, MapColourModeFollowsTheMaps) {
  // With blend 1 the colour is that of the last map applied, and each
  // octant's voxels are reached last by the map of that octant.
  ChaosGameParams params = OctantCloud(1'000'000, 16, 0.0);
  params.color = {ColorMode::kMap, 1.0};
  const CountGrid counts = RunGame(params, 2);
  int checked = 0;
  for (int x = 0; x < 16; ++x)
    for (int y = 0; y < 16; ++y)
      for (int z = 0; z < 16; ++z) {
        const uint32_t c = counts.Get(x, y, z);
        if (c == 0 || x == 8 || y == 8 || z == 8 || x == 7 || y == 7 || z == 7) continue;
        const int octant = (x >= 8) + 2 * (y >= 8) + 4 * (z >= 8);
        const double mean = double(counts.GetColorSum(x, y, z)) / c / CountGrid::kColorScale;
        EXPECT_NEAR(mean, octant / 7.0, 1e-4) << x << "," << y << "," << z;
        ++checked;
      }
  EXPECT_GT(checked, 500);
}

// The chaos game written the simple way: one walker after another, each
// with its own stream, counting into a dense array.
struct Reference {
  std::vector<uint32_t> counts;
  std::vector<uint64_t> color;
  uint64_t outside = 0, reseeded = 0;
};
Reference ReferenceLoop(const ChaosGameParams& params) {
  const Int3 r = params.frame.resolution;
  Reference ref;
  ref.counts.assign(size_t(r.x) * r.y * r.z, 0);
  ref.color.assign(ref.counts.size(), 0);
  const AliasTable table(params.ifs.probabilities);
  const Vec3 vs = params.frame.VoxelSize();
  const double ix = 1.0 / vs.x, iy = 1.0 / vs.y, iz = 1.0 / vs.z;
  const Bounds& b = params.frame.bounds;
  const int n_maps = int(params.ifs.maps.size());
  const bool colored = params.color.mode != ColorMode::kNone;
  constexpr int W = ChaosGame::kWalkers;
  for (uint64_t chunk = 0; chunk * ChaosGame::kChunkIterations < params.iterations; ++chunk) {
    const uint64_t count = std::min(ChaosGame::kChunkIterations,
                                    params.iterations - chunk * ChaosGame::kChunkIterations);
    for (int k = 0; k < W; ++k) {
      Rng rng(params.seed, chunk * W + k);
      Vec3 pos;
      double addr = 0, col = 0;
      auto step = [&] {
        const uint32_t m = table.Sample(rng.Next());
        pos = params.ifs.maps[m].pre.Apply(pos);
        addr = (double(m) + addr) * (1.0 / n_maps);
        col += params.color.blend * (addr - col);
        return IsFinite(pos);
      };
      auto random_point = [&] {
        const double x = rng.Uniform(b.min.x, b.max.x), y = rng.Uniform(b.min.y, b.max.y);
        return Vec3{x, y, rng.Uniform(b.min.z, b.max.z)};
      };
      auto warm_up = [&] {
        pos = random_point();
        if (colored) addr = col = rng.Uniform();
        for (uint32_t i = 0; i < params.warmup; ++i)
          if (!step()) {
            pos = random_point();
            ++ref.reseeded;
          }
      };
      warm_up();
      // Walker k plots steps k, k + W, k + 2W, ... of the chunk.
      for (uint64_t i = k; i < count; i += W) {
        if (!step()) {
          ++ref.reseeded;
          warm_up();
          continue;
        }
        const double fx = (pos.x - b.min.x) * ix, fy = (pos.y - b.min.y) * iy,
                     fz = (pos.z - b.min.z) * iz;
        if (!(fx >= 0 && fx < r.x && fy >= 0 && fy < r.y && fz >= 0 && fz < r.z)) {
          ++ref.outside;
          continue;
        }
        const size_t v = (size_t(fx) * r.y + size_t(fy)) * r.z + size_t(fz);
        ++ref.counts[v];
        if (colored)
          ref.color[v] += uint32_t(std::clamp(col, 0.0, 1.0) * CountGrid::kColorScale + 0.5);
      }
    }
  }
  return ref;
}

void ExpectMatchesReference(const ChaosGameParams& params, int threads,
                            ChaosGameStats* out = nullptr) {
  ChaosGameStats stats;
  const CountGrid sparse = RunGame(params, threads, &stats);
  const Reference ref = ReferenceLoop(params);
  const Int3 r = params.frame.resolution;
  uint64_t total = 0;
  for (int x = 0; x < r.x; ++x)
    for (int y = 0; y < r.y; ++y)
      for (int z = 0; z < r.z; ++z) {
        const size_t v = (size_t(x) * r.y + y) * r.z + z;
        ASSERT_EQ(sparse.Get(x, y, z), ref.counts[v]) << x << "," << y << "," << z;
        ASSERT_EQ(sparse.GetColorSum(x, y, z), ref.color[v]);
        total += ref.counts[v];
      }
  EXPECT_EQ(total, sparse.Total());
  EXPECT_EQ(stats.outside, ref.outside);
  EXPECT_EQ(stats.reseeded, ref.reseeded);
  EXPECT_EQ(stats.iterations_done, params.iterations);
  EXPECT_GT(total, params.iterations / 4);
  if (out) *out = stats;
}

TEST(ChaosGameColor, SparseAccumulationMatchesAReferenceLoop) {
  // The engine's binned, deferred, per-thread accumulation against a plain
  // dense array filled by the same walk written the simple way.
  ChaosGameParams params = OctantCloud(ChaosGame::kChunkIterations * 3 + 12345, 24);
  params.color.mode = ColorMode::kAddress;
  params.warmup = 20;
  ASSERT_FALSE(ChaosGame::UsesFastPath(params));
  ExpectMatchesReference(params, 2);
}

// The octant cloud on a grid that crops it (points leave the grid), plus a
// ninth map that overflows to infinity (walkers restart).
ChaosGameParams CroppedWithBlowUp(uint64_t iterations) {
  ChaosGameParams params = OctantCloud(iterations, 40);
  params.frame.bounds = {{-1.0, -1.2, -0.9}, {1.1, 0.8, 1.2}};
  PointMap blow_up;
  blow_up.pre = Affine3::Scale({1e300, 1e300, 1e300});
  params.ifs.maps.push_back(blow_up);
  params.ifs.probabilities.assign(9, 0.124);
  params.ifs.probabilities.back() = 0.008;
  return params;
}

std::vector<SimdLevel> SimdLevelsOfThisCpu() {
  std::vector<SimdLevel> levels = {SimdLevel::kScalar};
  if (DetectSimd() >= SimdLevel::kAvx2) levels.push_back(SimdLevel::kAvx2);
  if (DetectSimd() >= SimdLevel::kAvx512) levels.push_back(SimdLevel::kAvx512);
  return levels;
}

// The fast path (affine_walk kernels into TileBins, binned or incremented
// at once) at every SIMD level the CPU has.
TEST(ChaosGameFastPath, MatchesTheReferenceLoopAtEverySimdLevel) {
  ChaosGameParams params = CroppedWithBlowUp(ChaosGame::kChunkIterations * 2 + 777);
  ASSERT_TRUE(ChaosGame::UsesFastPath(params));
  for (const bool direct : {false, true})
    for (SimdLevel level : SimdLevelsOfThisCpu()) {
      SCOPED_TRACE(std::string(SimdName(level)) + (direct ? " direct" : " binned"));
      params.simd = level;
      params.direct_increments = direct;
      ChaosGameStats stats;
      ExpectMatchesReference(params, 2, &stats);
      EXPECT_GT(stats.outside, params.iterations / 10);
      EXPECT_GT(stats.reseeded, 1000u);
    }
}

// Each way of finding a map's coefficients in the AVX2 kernel (up to 4 maps:
// one permute, up to 8: two, more: gathers) and the AVX-512 kernel (up to 8:
// one permute, more: gathers).
TEST(ChaosGameFastPath, SimdLevelsAgreeForEveryMapCount) {
  if (DetectSimd() < SimdLevel::kAvx2) GTEST_SKIP() << "no AVX2 on this CPU";
  for (int maps : {1, 3, 5, 8, 11}) {
    SCOPED_TRACE(maps);
    ChaosGameParams params = OctantCloud(300'000 + maps, 32);
    params.ifs.maps.resize(8);
    for (int i = 8; i < maps; ++i) {
      PointMap m;
      m.pre = Affine3::Translate({0.1 * i - 1, 0.3, -0.2}) * Affine3::Scale({0.3, 0.4, 0.35});
      params.ifs.maps.push_back(m);
    }
    params.ifs.maps.resize(maps);
    params.ifs.probabilities.clear();
    for (int i = 0; i < maps; ++i) params.ifs.probabilities.push_back(1.0 + i);
    params.simd = SimdLevel::kScalar;
    params.direct_increments = false;
    ChaosGameStats scalar_stats;
    const CountGrid scalar = RunGame(params, 1, &scalar_stats);
    EXPECT_GT(scalar.Total(), 0u);
    for (const bool direct : {false, true})
      for (SimdLevel level : SimdLevelsOfThisCpu()) {
        SCOPED_TRACE(std::string(SimdName(level)) + (direct ? " direct" : " binned"));
        params.simd = level;
        params.direct_increments = direct;
        ChaosGameStats stats;
        const CountGrid got = RunGame(params, 2, &stats);
        ExpectSameGrids(scalar, got);
        EXPECT_EQ(scalar_stats.outside, stats.outside);
      }
  }
}

// Same counters, tile by tile (faster than voxel by voxel on big grids).
void ExpectSameTiles(const CountGrid& a, const CountGrid& b) {
  ASSERT_EQ(a.AllocatedTiles(), b.AllocatedTiles());
  ASSERT_EQ(a.TileCount(), b.TileCount());
  for (size_t t = 0; t < a.TileCount(); ++t) {
    const uint32_t *ta = a.TileOrNull(t), *tb = b.TileOrNull(t);
    ASSERT_EQ(ta == nullptr, tb == nullptr) << t;
    if (ta) {
      ASSERT_EQ(std::memcmp(ta, tb, CountGrid::kTileVoxels * sizeof(uint32_t)), 0) << t;
    }
  }
}

// On a grid of more tiles than TileBins::kSplitTiles the binned sink
// partitions in two passes; with two threads it fills one shared grid or
// one grid per thread. Every sink and SIMD level counts what the scalar
// kernel counts into one binned grid. A small budget makes pools flush
// mid-run.
TEST(ChaosGameFastPath, EverySinkAgreesOnAGridSplitInTwoPasses) {
  ChaosGameParams params = OctantCloud(3'000'000, 544);
  params.frame.bounds = {{-2, -2, -2}, {17, 17, 17}};  // about 4^3 of 17^3 tiles
  params.memory_budget = uint64_t{32} << 20;
  ASSERT_GT(TileBins::BinShift(params.frame.resolution), 0u);
  params.simd = SimdLevel::kScalar;
  params.direct_increments = false;
  ChaosGameStats want;
  const CountGrid reference = RunGame(params, 1, &want);
  EXPECT_GT(reference.AllocatedTiles(), 8u);
  for (const bool direct : {false, true})
    for (const bool shared : {false, true})
      for (SimdLevel level : SimdLevelsOfThisCpu()) {
        if (direct && shared) continue;  // direct increments never share
        std::string label(SimdName(level));
        label += direct ? " direct" : shared ? " binned, shared" : " binned";
        SCOPED_TRACE(label);
        params.simd = level;
        params.direct_increments = direct;
        params.shared_grid = shared;
        ChaosGameStats got;
        auto game = ChaosGame::Create(params, 2);
        ASSERT_TRUE(game.ok()) << game.status();
        ASSERT_TRUE((*game)->Run(nullptr).ok());
        EXPECT_EQ((*game)->partial_counts().size(), shared ? 1u : 2u);
        got = (*game)->stats();
        ExpectSameTiles(reference, (*game)->TakeCounts());
        EXPECT_EQ(got.outside, want.outside);
      }
}

// A Markov chain on the fast path: two states, one unplotted, over the
// cropped cloud with its overflowing map. Scalar and AVX2 kernels must count
// exactly what the general path counts (forced by an identity final map).
TEST(ChaosGameFastPath, ChainsMatchTheGeneralPathAtEverySimdLevel) {
  // With 9 maps the AVX2 kernel gathers the coefficients; with 4 it
  // permutes them.
  for (const size_t num_maps : {9, 4}) {
    SCOPED_TRACE(num_maps);
    ChaosGameParams params = CroppedWithBlowUp(ChaosGame::kChunkIterations * 2 + 99);
    params.ifs.maps.erase(params.ifs.maps.begin() + (num_maps - 1), params.ifs.maps.end() - 1);
    params.ifs.probabilities.assign(num_maps, 1.0 / double(num_maps));
    const uint32_t blow_up = uint32_t(num_maps - 1);
    MarkovChain chain;
    ChainState plotted, hidden;
    for (uint32_t m = 0; m < blow_up; ++m)
      plotted.transitions.push_back({m, m < blow_up / 2 + 1 ? 0u : 1u});
    plotted.probabilities.assign(plotted.transitions.size(),
                                 1.0 / double(plotted.transitions.size()));
    hidden.transitions = {{1, 0}, {2, 1}, {blow_up, 0}};
    hidden.probabilities = {0.6, 0.398, 0.002};
    hidden.plotted = false;
    chain.states = {plotted, hidden};
    chain.start_state = 1;
    params.chain = chain;
    ASSERT_TRUE(ChaosGame::UsesFastPath(params));

    ChaosGameParams general = params;
    general.ifs.final_map = PointMap{};
    ASSERT_FALSE(ChaosGame::UsesFastPath(general));
    ChaosGameStats want;
    const CountGrid reference = RunGame(general, 2, &want);
    EXPECT_GT(want.reseeded, 100u);
    EXPECT_GT(want.outside, 1000u);

    for (const bool direct : {false, true})
      for (SimdLevel level : SimdLevelsOfThisCpu()) {
        SCOPED_TRACE(std::string(SimdName(level)) + (direct ? " direct" : " binned"));
        params.simd = level;
        params.direct_increments = direct;
        ChaosGameStats got;
        ExpectSameGrids(reference, RunGame(params, 2, &got));
        EXPECT_EQ(got.reseeded, want.reseeded);
        EXPECT_EQ(got.outside, want.outside);
      }
  }
}

TEST(ChaosGameFastPath, PlainIfsMatchesTheGeneralPathBitwise) {
  // An identity final transform sends the job down the general path; a
  // one-state chain too. Both must count exactly what the fast path counts.
  ChaosGameParams params = OctantCloud(ChaosGame::kChunkIterations + 4321, 48);
  const CountGrid fast = RunGame(params, 2);
  params.ifs.final_map = PointMap{};
  ASSERT_FALSE(ChaosGame::UsesFastPath(params));
  ExpectSameGrids(fast, RunGame(params, 2));
  params.ifs.final_map.reset();
  MarkovChain chain;
  ChainState state;
  for (uint32_t i = 0; i < 8; ++i) state.transitions.push_back({i, 0});
  state.probabilities = params.ifs.probabilities;
  chain.states = {state};
  params.chain = chain;
  ExpectSameGrids(fast, RunGame(params, 2));
}

TEST(ChaosGameColor, NonFiniteFinalTransformIsCountedNotPlotted) {
  ChaosGameParams params = OctantCloud(500'000, 16);
  PointMap bad;  // overflows every non-zero coordinate to infinity
  bad.pre = Affine3::Scale({1e300, 1e300, 1e300});
  bad.post = Affine3::Scale({1e300, 1e300, 1e300});
  params.ifs.final_map = bad;
  ChaosGameStats stats;
  const CountGrid counts = RunGame(params, 2, &stats);
  EXPECT_EQ(counts.Total(), 0u);
  EXPECT_EQ(stats.final_nonfinite, params.iterations);
  EXPECT_EQ(stats.outside, params.iterations);
}

TEST(ChaosGameColor, MemoryEstimateIsBoundedByIterationsAndGrid) {
  ChaosGameParams params = OctantCloud(1000, 2048);
  const ChaosGameMemory small = ChaosGame::EstimateMemory(params, 2, 4);
  // 1000 steps touch at most ~1000 tiles of 128 KiB, not the 2048^3 grid.
  EXPECT_LT(small.peak(), uint64_t{1} << 30);
  params.iterations = uint64_t{1} << 36;
  const ChaosGameMemory big = ChaosGame::EstimateMemory(params, 2, 4);
  // One full 32 GiB counter grid, which the binned threads share: the grid
  // bound, not the iterations; the other thread may add 256 tiles.
  const uint64_t grid = CountGrid::MaxMemoryBytes({2048, 2048, 2048});
  const uint64_t direct = 256 * CountGrid::TileBytes(false);
  EXPECT_GE(big.accumulation, grid - (1 << 24));
  // ... plus two key buffers of at most 2^25 keys x 16 bytes.
  EXPECT_LE(big.accumulation, grid + direct + (uint64_t{1} << 24) + 2 * (uint64_t{16} << 25));
  // A grid per thread when they do not share.
  params.shared_grid = false;
  const ChaosGameMemory apart = ChaosGame::EstimateMemory(params, 2, 4);
  EXPECT_GE(apart.accumulation, 2 * grid - (1 << 24));
  EXPECT_LE(apart.accumulation, 2 * grid + 2 * (uint64_t{16} << 25));
  // And the real run stays within the estimate.
  params = OctantCloud(3'000'000, 128);
  params.color.mode = ColorMode::kAddress;
  auto game = ChaosGame::Create(params, 2);
  ASSERT_TRUE(game.ok());
  ASSERT_TRUE((*game)->Run(nullptr).ok());
  EXPECT_LE((*game)->MemoryBytes(), ChaosGame::EstimateMemory(params, 2, 16).accumulation);
}

// All points at one spot: the IFS whose only map sends everything to `at`.
ChaosGameParams FixedPoint(Vec3 at, uint64_t iterations) {
  ChaosGameParams p;
  PointMap m;
  m.pre = Affine3::Translate(at) * Affine3::Scale({0, 0, 0});
  p.ifs.maps = {m};
  p.ifs.probabilities = {1};
  p.frame.resolution = {8, 8, 8};
  p.frame.bounds = {{0, 0, 0}, {8, 8, 8}};  // voxel i spans [i, i + 1)
  p.iterations = iterations;
  p.splat = true;
  return p;
}

TEST(ChaosGameSplat, WeightsFollowThePositionBetweenVoxelCentres) {
  // At a voxel centre: the whole point in that voxel.
  CountGrid centre = RunGame(FixedPoint({3.5, 4.5, 5.5}, 1000), 2);
  EXPECT_EQ(centre.Get(3, 4, 5), 1000 * kSplatScale);
  EXPECT_EQ(centre.Total(), 1000 * kSplatScale);
  // At a voxel corner: an eighth in each of the 8 voxels around it.
  CountGrid corner = RunGame(FixedPoint({3, 4, 5}, 1000), 2);
  for (int c = 0; c < 8; ++c)
    EXPECT_EQ(corner.Get(2 + (c & 1), 3 + ((c >> 1) & 1), 4 + (c >> 2)), 1000 * 8);
  // A quarter of the way from centre 3.5 to 4.5 in x: 3/4 and 1/4.
  CountGrid quarter = RunGame(FixedPoint({3.75, 4.5, 5.5}, 1000), 1);
  EXPECT_EQ(quarter.Get(3, 4, 5), 1000 * 48);
  EXPECT_EQ(quarter.Get(4, 4, 5), 1000 * 16);
  // Beyond the outermost centres the weight folds onto the border voxel.
  CountGrid border = RunGame(FixedPoint({0.1, 4.5, 5.5}, 1000), 1);
  EXPECT_EQ(border.Get(0, 4, 5), 1000 * kSplatScale);
}

TEST(ChaosGameSplat, ReproducibleAndMassPreserving) {
  ChaosGameParams params = OctantCloudParams(32, 2'000'000);
  params.splat = true;
  params.color.mode = ColorMode::kAddress;
  ChaosGameStats stats;
  const CountGrid one = RunGame(params, 1, &stats);
  ExpectSameGrids(one, RunGame(params, 2));
  EXPECT_EQ(one.Total(), (params.iterations - stats.outside) * kSplatScale);
  // Splatting smooths: more voxels are hit than without it.
  params.splat = false;
  const CountGrid plain = RunGame(params, 1);
  size_t hit_splat = 0, hit_plain = 0;
  for (int x = 0; x < 32; ++x)
    for (int y = 0; y < 32; ++y)
      for (int z = 0; z < 32; ++z) {
        hit_splat += one.Get(x, y, z) > 0;
        hit_plain += plain.Get(x, y, z) > 0;
      }
  EXPECT_GE(hit_splat, hit_plain);
}

TEST(ChaosGameColor, DensityChangeMeasuresConvergence) {
  ChaosGameParams params = OctantCloud(uint64_t{1} << 23, 64);
  auto game = ChaosGame::Create(params, 2);
  ASSERT_TRUE(game.ok());
  auto coarse = [&] {
    std::vector<const CountGrid*> parts;
    for (const CountGrid& g : (*game)->partial_counts()) parts.push_back(&g);
    return CoarseCounts(parts, 32);
  };
  ASSERT_TRUE((*game)->RunUntil(uint64_t{1} << 21, nullptr).ok());
  const auto a = coarse();
  ASSERT_TRUE((*game)->RunUntil(uint64_t{1} << 22, nullptr).ok());
  const auto b = coarse();
  ASSERT_TRUE((*game)->RunUntil(uint64_t{1} << 23, nullptr).ok());
  const auto c = coarse();
  EXPECT_EQ(DensityChange(a, a), 0.0);
  EXPECT_GT(DensityChange(a, b), 0.0);
  EXPECT_LT(DensityChange(b, c), 0.05);  // a uniform cloud converges fast
  EXPECT_EQ(DensityChange({1, 0}, {0, 1}), 2.0);
}

// A random contractive IFS of 3 to 6 maps, planar (z's row (0, 0, 0, c)
// with one c for every map, no z column in x and y: walk::AffineWalk's
// planar case) or not, plus a rare map to infinity. Some zero coefficients
// are -0.0, and a planar IFS's bounds may start at 0 on x, where the
// points of a map to x = 0 land with either sign of zero. `equal`: equal
// probabilities (every map its own alias) and no map to infinity.
ChaosGameParams RandomIfs(uint64_t seed, bool planar, uint64_t iterations, bool equal = false) {
  Rng rng(seed, 99);
  ChaosGameParams p;
  const int maps = 3 + int(rng.Next() % 4);
  const double c = planar && rng.Next() % 2 ? 0.0 : 0.3;
  for (int i = 0; i < maps; ++i) {
    PointMap m;
    for (int r = 0; r < 3; ++r)
      for (int col = 0; col < 4; ++col) m.pre.m[r][col] = rng.Uniform(-0.45, 0.45);
    if (planar) {
      m.pre.m[0][2] = m.pre.m[1][2] = i % 2 ? -0.0 : 0.0;
      m.pre.m[2] = {0.0, -0.0, 0.0, c};
      // Odd seeds: map 0 sends x to a zero (-0 when x and y are negative,
      // whose skipped z term would have made it +0), on the grid's edge.
      if (i == 0 && seed % 2) m.pre.m[0] = {0.0, 0.0, -0.0, -0.0};
    }
    p.ifs.maps.push_back(m);
    const double q = rng.Uniform(0.5, 2);
    p.ifs.probabilities.push_back(equal ? 1.0 : q);
  }
  if (!equal) {
    PointMap blow_up;
    blow_up.pre = Affine3::Scale({1e300, 1e300, 1e300});
    p.ifs.maps.push_back(blow_up);
    p.ifs.probabilities.push_back(0.01);
  }
  const double lo = planar && seed % 2 ? 0.0 : -0.6;
  p.frame.bounds = {{lo, -0.6, -0.6}, {0.6, 0.6, 0.6}};
  p.frame.resolution = planar ? Int3{96, 80, 1} : Int3{40, 36, 44};
  p.iterations = iterations;
  p.seed = seed;
  return p;
}

// The flat direct mode (small lattices) and the planar AVX-512 walk count
// exactly what the scalar kernel counts into a binned grid, on random 2D
// and 3D IFS, volumes and pictures, one and two threads; a lattice over
// TileBins::kFlatVoxels takes the table of tiles instead, and agrees too.
// Equal probabilities take the AVX-512 walk without the alias test, and
// pictures its pixel-unit variant.
TEST(ChaosGameFastPath, FlatAndPlanarWalksCountAsTheScalarBinnedOne) {
  const uint64_t n = ChaosGame::kChunkIterations * 2 + 333;  // a partial round too
  struct Case {
    uint64_t seed;
    bool planar, picture, big, equal = false;
  };
  const Case cases[] = {{1, true, false, false},       {2, true, false, false},
                        {3, true, true, false},        {4, false, false, false},
                        {5, false, false, true},       {6, true, false, true},
                        {7, true, true, false, true},  {8, true, false, false, true},
                        {9, false, false, false, true}};
  for (const Case& c : cases) {
    ChaosGameParams params = RandomIfs(c.seed, c.planar, n, c.equal);
    if (c.picture) params.image = MakeImagePlane({}, params.frame.bounds, 120, 90);
    if (c.big) params.frame.resolution = c.planar ? Int3{2048, 1100, 1} : Int3{140, 128, 128};
    const Int3 lattice = c.picture ? Int3{120, 90, 1} : params.frame.resolution;
    ASSERT_EQ(TileBins::Flat(lattice), !c.big);
    ASSERT_TRUE(ChaosGame::UsesFastPath(params));
    SCOPED_TRACE(::testing::Message() << "seed " << c.seed << (c.planar ? " planar" : " 3D")
                                    << (c.picture ? " picture" : "") << (c.big ? " big" : "")
                                    << (c.equal ? " equal" : ""));
    params.simd = SimdLevel::kScalar;
    params.direct_increments = false;
    ChaosGameStats want_stats;
    const CountGrid want = RunGame(params, 1, &want_stats);
    EXPECT_GT(want.Total(), n / 4);
    EXPECT_GT(want_stats.outside, 0u);
    if (!c.equal) {
      EXPECT_GT(want_stats.reseeded, 0u);
    }
    for (const bool direct : {false, true})
      for (SimdLevel level : SimdLevelsOfThisCpu())
        for (const int threads : {1, 2}) {
          SCOPED_TRACE(::testing::Message() << SimdName(level) << (direct ? " direct " : " binned ")
                                          << threads << " threads");
          params.simd = level;
          params.direct_increments = direct;
          ChaosGameStats stats;
          const CountGrid got = RunGame(params, threads, &stats);
          ExpectSameTiles(want, got);
          EXPECT_EQ(stats.outside, want_stats.outside);
          EXPECT_EQ(stats.reseeded, want_stats.reseeded);
        }
  }
}

}  // namespace
}  // namespace nimbus
