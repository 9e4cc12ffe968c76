// Grids one voxel thick (resolution z == 1) are stored folded: 32 rows in
// each tile's depth (CountGrid). The fold must be invisible: a thin run
// counts exactly what the same run counts on an unfolded grid, through the
// affine kernels of every SIMD level, the flame path, colour, splatting,
// shards and the VDB writer, while holding 1/32 of the tiles.
#include <gtest/gtest.h>

#include <array>
#include <map>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#include "core/chaos/chaos_game.h"
#include "core/chaos/chaos_partial.h"
#include "core/chaos/key_bins.h"
#include "core/io/vdb_io.h"
#include "tests/support/count_scatter.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

// A 2D map: rows 1 and 2 of [A | b] in the x-y plane, z sent to 0.
PointMap Map2d(double a, double b, double c, double d, double e, double f) {
  PointMap m;
  m.pre.m[0] = {a, b, 0, c};
  m.pre.m[1] = {d, e, 0, f};
  m.pre.m[2] = {0, 0, 0, 0};
  return m;
}

// The Sierpinski triangle of bench/flam3/sierpinski_2d.json on a W x H x 1
// grid over [-0.1, 1.1]^2 x [-0.5, 0.5].
ChaosGameParams Sierpinski2d(int w, int h, uint64_t iterations) {
  ChaosGameParams p;
  p.ifs.maps = {Map2d(0.5, 0, 0, 0, 0.5, 0), Map2d(0.5, 0, 0.5, 0, 0.5, 0),
                Map2d(0.5, 0, 0.25, 0, 0.5, 0.5)};
  p.ifs.probabilities = {1.0 / 3, 1.0 / 3, 1.0 / 3};
  p.frame.resolution = {w, h, 1};
  p.frame.bounds = {{-0.1, -0.1, -0.5}, {1.1, 1.1, 0.5}};
  p.iterations = iterations;
  p.seed = 11;
  return p;
}

// A three-map flame with six variations, colour by map (the genome of
// bench/flam3/flame6_2d.json) over [-2, 2]^2 x [-0.5, 0.5].
ChaosGameParams Flame2d(int w, int h, uint64_t iterations) {
  ChaosGameParams p;
  PointMap a = Map2d(0.55, -0.25, 0.3, 0.25, 0.55, 0.1);
  a.variations = {{VariationKind::kSwirl, 0.6}, {VariationKind::kSpherical, 0.4}};
  a.color = 0.1;
  PointMap b = Map2d(0.7, 0.2, -0.4, -0.2, 0.7, 0.5);
  b.variations = {{VariationKind::kJulia, 0.8}, {VariationKind::kSinusoidal, 0.2}};
  b.color = 0.5;
  PointMap c = Map2d(0.5, 0, 0, 0, 0.5, -0.3);
  c.variations = {{VariationKind::kBubble, 0.5}, {VariationKind::kPolar, 0.5}};
  c.color = 0.9;
  p.ifs.maps = {a, b, c};
  p.ifs.probabilities = {0.4, 0.35, 0.25};
  p.frame.resolution = {w, h, 1};
  p.frame.bounds = {{-2, -2, -0.5}, {2, 2, 0.5}};
  p.iterations = iterations;
  p.seed = 3;
  p.color = {ColorMode::kMap, 0.5};
  return p;
}

// The unfolded reference of a thin run: the same grid two voxels thick,
// grown by one voxel in z. Voxel sizes and walks are the same, every point
// lands in slice 0, and a grid of depth 2 is stored as it is.
ChaosGameParams Unfolded(ChaosGameParams p) {
  p.frame.resolution.z = 2;
  p.frame.bounds.max.z += p.frame.bounds.max.z - p.frame.bounds.min.z;
  return p;
}

CountGrid RunGame(const ChaosGameParams& p, int threads) {
  auto game = ChaosGame::Create(p, threads);
  EXPECT_TRUE(game.ok()) << game.status();
  EXPECT_TRUE((*game)->Run(nullptr).ok());
  return (*game)->TakeCounts();
}

// Every voxel of `thin` equals slice 0 of `ref`, whose slice 1 is empty.
void ExpectSameCounts(const CountGrid& thin, const CountGrid& ref) {
  ASSERT_TRUE(thin.folded());
  ASSERT_FALSE(ref.folded());
  const Int3 r = thin.resolution();
  uint64_t differing = 0, lit = 0;
  for (int x = 0; x < r.x; ++x)
    for (int y = 0; y < r.y; ++y) {
      differing += thin.Get(x, y, 0) != ref.Get(x, y, 0) ||
                   thin.GetColorSum(x, y, 0) != ref.GetColorSum(x, y, 0) || ref.Get(x, y, 1);
      lit += thin.Get(x, y, 0) != 0;
    }
  EXPECT_EQ(differing, 0u);
  EXPECT_GT(lit, uint64_t(r.x) * r.y / 50);  // not trivially empty
  EXPECT_EQ(thin.Total(), ref.Total());
  EXPECT_EQ(thin.Max(), ref.Max());
  // ForEachVoxel names the same voxels as Get.
  uint64_t seen = 0;
  thin.ForEachVoxel([&](Int3 v, uint32_t n) {
    ++seen;
    if (v.z != 0 || n != ref.Get(v.x, v.y, 0)) ++differing;
  });
  EXPECT_EQ(seen, lit);
  EXPECT_EQ(differing, 0u);
}

TEST(ThinGrid, FoldedCountGridRoundTripsEveryVoxel) {
  const Int3 r{77, 1000, 1};  // neither axis a multiple of 32
  CountGrid g(r, true);
  EXPECT_TRUE(g.folded());
  EXPECT_EQ(CountGrid::StorageResolution(r), (Int3{77, 32, 32}));
  EXPECT_EQ(g.tiles(), (Int3{3, 1, 1}));
  std::map<std::tuple<int, int>, uint32_t> want;
  for (int i = 0; i < 5000; ++i) {
    const int x = (i * 37) % r.x, y = (i * 101 + i / 7) % r.y;
    g.Add(x, y, 0, 1 + i % 3);
    want[{x, y}] += 1 + i % 3;
  }
  for (const auto& [xy, n] : want) EXPECT_EQ(g.Get(std::get<0>(xy), std::get<1>(xy), 0), n);
  size_t seen = 0;
  g.ForEachVoxel([&](Int3 v, uint32_t n) {
    ++seen;
    EXPECT_EQ(v.z, 0);
    EXPECT_EQ(want[std::make_tuple(v.x, v.y)], n);
  });
  EXPECT_EQ(seen, want.size());
  // Leaves: OpenVDB order, the voxel leaf's z = 0 slice only.
  size_t in_leaves = 0;
  g.ForEachLeaf([&](Int3 o, const uint32_t* v, const uint64_t* c) {
    EXPECT_NE(c, nullptr);
    EXPECT_EQ(o.x % 8 + o.y % 8 + o.z, 0);
    for (int i = 0; i < 512; ++i) {
      if (!v[i]) continue;
      ++in_leaves;
      EXPECT_EQ(i & 7, 0);
      EXPECT_EQ(v[i], g.Get(o.x + (i >> 6), o.y + ((i >> 3) & 7), 0));
    }
  });
  EXPECT_EQ(in_leaves, want.size());
  // 3 tiles instead of 3 x 32.
  EXPECT_EQ(g.AllocatedTiles(), 3u);
  EXPECT_EQ(CountGrid::TileCountFor(r), 3u);
  EXPECT_FALSE(CountGrid::Folds({64, 64, 2}));
}

TEST(ThinGrid, AffineKernelsCountAsUnfolded) {
  const ChaosGameParams p = Sierpinski2d(200, 333, 3'000'000);
  ASSERT_TRUE(ChaosGame::UsesFastPath(p));
  for (SimdLevel level : {SimdLevel::kScalar, SimdLevel::kAvx2, SimdLevel::kAvx512}) {
    if (level > DetectSimd()) continue;
    SCOPED_TRACE(int(level));
    ChaosGameParams q = p;
    q.simd = level;
    ExpectSameCounts(RunGame(q, 2), RunGame(Unfolded(q), 1));
  }
}

TEST(ThinGrid, GeneralPathWithColourCountsAsUnfolded) {
  ChaosGameParams p = Sierpinski2d(130, 257, 2'000'000);
  p.color = {ColorMode::kAddress, 0.3};
  ASSERT_FALSE(ChaosGame::UsesFastPath(p));
  ExpectSameCounts(RunGame(p, 2), RunGame(Unfolded(p), 2));
}

TEST(ThinGrid, FlamePathCountsAsUnfolded) {
  const ChaosGameParams p = Flame2d(160, 100, 2'000'000);
  ExpectSameCounts(RunGame(p, 2), RunGame(Unfolded(p), 1));
}

// A 200 x 200 picture with colour packs its keys (7 folded tiles) and its
// threads share one grid; the unfolded reference (49 tiles) bins them into
// a grid per thread. Same counts and colour sums at every SIMD level, with
// the grid shared or not.
TEST(ThinGrid, PackedKeysCountAsBinnedAtEverySimdLevel) {
  ChaosGameParams p = Flame2d(200, 200, 1'500'000);
  ASSERT_TRUE(KeyBins::Packs(p.CountResolution(), true));
  ASSERT_FALSE(KeyBins::Packs(Unfolded(p).CountResolution(), true));
  for (int level = 0; level <= int(DetectSimd()); ++level) {
    SCOPED_TRACE(level);
    p.simd = SimdLevel(level);
    ExpectSameCounts(RunGame(p, 2), RunGame(Unfolded(p), 2));
    p.shared_grid = false;
    ExpectSameCounts(RunGame(p, 2), RunGame(Unfolded(p), 1));
    p.shared_grid.reset();
  }
}

// Packed words stay unfolded between rounds until the partial counts are
// read: read mid-run they hold every step so far (as a game stopped there
// does), and rounds, read or not, leave the final counts as one run's.
TEST(ThinGrid, PackedRoundsFoldWhenReadAndAtTheEnd) {
  const uint64_t n = 12 * ChaosGame::kChunkIterations;
  const ChaosGameParams p = Flame2d(200, 200, n);
  ASSERT_TRUE(KeyBins::Packs(p.CountResolution(), true));
  ChaosGameParams half = p;
  half.iterations = n / 2;
  const CountGrid at_half = RunGame(half, 2);
  auto game = ChaosGame::Create(p, 2);
  ASSERT_TRUE(game.ok()) << game.status();
  ASSERT_TRUE((*game)->RunUntil(ChaosGame::kChunkIterations, nullptr).ok());
  ASSERT_TRUE((*game)->RunUntil(n / 4, nullptr).ok());  // left unfolded: nobody reads
  ASSERT_TRUE((*game)->RunUntil(n / 2, nullptr).ok());
  const std::vector<CountGrid>& parts = (*game)->partial_counts();
  ASSERT_EQ(parts.size(), 1u);  // the threads share one grid
  EXPECT_EQ(parts[0].Total(), at_half.Total());
  EXPECT_EQ(parts[0].Max(), at_half.Max());
  ASSERT_TRUE((*game)->RunUntil(3 * n / 4, nullptr).ok());
  // A last round of one chunk: the other thread sits it out, holding words.
  ASSERT_TRUE((*game)->RunUntil(n - ChaosGame::kChunkIterations, nullptr).ok());
  ASSERT_TRUE((*game)->Run(nullptr).ok());
  ExpectSameCounts((*game)->TakeCounts(), RunGame(Unfolded(p), 1));
  // Stopped before the last round and taken at once: nothing is lost.
  auto stopped = ChaosGame::Create(half, 2);
  ASSERT_TRUE(stopped.ok());
  ASSERT_TRUE((*stopped)->RunUntil(n / 4, nullptr).ok());
  ASSERT_FALSE((*stopped)->done());
  const ChaosGameStats s = (*stopped)->stats();
  EXPECT_GT(s.iterations_done, 0u);
  EXPECT_EQ((*stopped)->TakeCounts().Total(), s.iterations_done - s.outside - s.reseeded);
}

TEST(ThinGrid, SplatCountsAsUnfolded) {
  ChaosGameParams p = Flame2d(96, 70, 1'000'000);
  p.splat = true;
  ExpectSameCounts(RunGame(p, 2), RunGame(Unfolded(p), 2));
}

TEST(ThinGrid, ShardPartialsKeepTheFold) {
  const ChaosGameParams p = Flame2d(120, 90, 5 * ChaosGame::kChunkIterations + 7);
  const CountGrid whole = RunGame(p, 2);
  testing::TempDir dir;
  CountGrid sum(p.frame.resolution, true);
  ChaosGameStats stats;
  for (uint32_t k = 0; k < 3; ++k) {
    ChaosGameParams q = p;
    std::tie(q.chunk_begin, q.chunk_end) = ChaosGame::ShardChunks(p.iterations, 3, k);
    auto game = ChaosGame::Create(q, 1);
    ASSERT_TRUE(game.ok());
    ASSERT_TRUE((*game)->Run(nullptr).ok());
    const ChaosGameStats s = (*game)->stats();
    const auto path = dir / ("shard-" + std::to_string(k));
    ASSERT_TRUE(SaveChaosPartial(path, (*game)->TakeCounts(), s).ok());
    ASSERT_TRUE(AddChaosPartialFile(path, sum, stats).ok());
  }
  EXPECT_EQ(stats.iterations_done, p.iterations);
  EXPECT_EQ(sum.AllocatedTiles(), whole.AllocatedTiles());
  ExpectSameCounts(sum, RunGame(Unfolded(p), 2));
  ExpectSameCounts(whole, RunGame(Unfolded(p), 2));
}

// The written grids hold the same voxels and values as the unfolded
// reference's, and a box-filtered (downsampled) result too.
TEST(ThinGrid, VdbEqualsTheUnfoldedReference) {
  const ChaosGameParams p = Flame2d(150, 120, 1'500'000);
  const CountGrid thin = RunGame(p, 2), ref = RunGame(Unfolded(p), 2);
  testing::TempDir dir;
  for (int max_voxels : {0, 2000}) {
    SCOPED_TRACE(max_voxels);
    DensityOptions o;
    o.color = true;
    o.raw_counts = RawCounts::kFloat;
    o.conventions.max_voxels = max_voxels;
    const auto a = dir / "thin.vdb", b = dir / "ref.vdb";
    ASSERT_TRUE(WriteDensityVdb(a, thin, p.frame, o, {}).ok());
    ASSERT_TRUE(WriteDensityVdb(b, ref, Unfolded(p).frame, o, {}).ok());
    EXPECT_EQ(OutputDownsampleFactor(thin, o), OutputDownsampleFactor(ref, o));
    for (const char* name : {"density", "counts"}) {
      auto va = ReadVdbFile(a, name), vb = ReadVdbFile(b, name);
      ASSERT_TRUE(va.ok() && vb.ok());
      const Int3 r = va->frame.resolution;
      ASSERT_EQ(r.z, 1);
      uint64_t differing = 0, active = 0;
      for (int x = 0; x < r.x; ++x)
        for (int y = 0; y < r.y; ++y) {
          differing += va->At(x, y, 0) != vb->At(x, y, 0);
          active += va->At(x, y, 0) != 0;
        }
      EXPECT_EQ(differing, 0u) << name;
      EXPECT_GT(active, 0u);
    }
    auto ca = ReadVec3VdbFile(a), cb = ReadVec3VdbFile(b);
    ASSERT_TRUE(ca.ok() && cb.ok());
    uint64_t differing = 0;
    for (int x = 0; x < ca->resolution.x; ++x)
      for (int y = 0; y < ca->resolution.y; ++y)
        differing += !(ca->At(x, y, 0) == cb->At(x, y, 0)) ||
                     ca->active[size_t(x) * ca->resolution.y + y] !=
                         cb->active[(size_t(x) * cb->resolution.y + y) * cb->resolution.z];
    EXPECT_EQ(differing, 0u);
  }
}

TEST(ThinGrid, PreviewDownsamplingAndCoarseCountsSeeVoxels) {
  const ChaosGameParams p = Flame2d(200, 150, 1'000'000);
  const CountGrid thin = RunGame(p, 1), ref = RunGame(Unfolded(p), 1);
  const CountGrid a = DownsampleCounts({&thin}, 3), b = DownsampleCounts({&ref}, 3);
  for (int x = 0; x < a.resolution().x; ++x)
    for (int y = 0; y < a.resolution().y; ++y) ASSERT_EQ(a.Get(x, y, 0), b.Get(x, y, 0));
  // Coarse cells of 32 voxels: the unfolded grid's cells are 32 deep too.
  EXPECT_EQ(CoarseCounts({&thin}, 8), CoarseCounts({&ref}, 8));
}

// A 2D job of 1024 x 1024 x 1 with colour (the flame of
// bench/compare_flam3.sh) on 2 threads: 32 folded tiles of 384 KiB per
// thread, where 32^3 tiles took 1024 (512 MiB estimated before).
TEST(ThinGrid, EstimateOfA1024SquarePictureIsSmall) {
  const ChaosGameParams p = Flame2d(1024, 1024, 104'857'600);
  const uint64_t per_voxel = 4 * sizeof(float);  // density and Cd
  const ChaosGameMemory m = ChaosGame::EstimateMemory(p, 2, per_voxel);
  EXPECT_LT(m.accumulation, uint64_t{40} << 20);
  // Output: the merged counts and a VDB leaf per 8 x 8 pixels.
  EXPECT_LT(m.output, uint64_t{180} << 20);
  EXPECT_LT(m.peak(), uint64_t{180} << 20);
  // The pilot counts folded tiles: at most the 32 there are.
  auto census = ChaosGame::Pilot(p, uint64_t{1} << 20, nullptr);
  ASSERT_TRUE(census.ok());
  EXPECT_LE(census->seen, 32u);
  EXPECT_GT(census->seen, 0u);
}

}  // namespace
}  // namespace nimbus
