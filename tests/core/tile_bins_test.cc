// TileBins: increments binned by tile as they are produced, applied on
// flush, including pool exhaustion and bins that hold several tiles.
#include "core/chaos/tile_bins.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <map>
#include <thread>
#include <tuple>
#include <vector>

#include "core/base/random.h"
#include "core/chaos/image_plane.h"
#include "core/grid/tile_arena.h"

namespace nimbus {
namespace {

// Pushes one increment of voxel (x, y, z) the way the walk kernels do.
void Push(TileBins& bins, const CountGrid& grid, int x, int y, int z) {
  const uint32_t tile = uint32_t((x >> 5) * grid.tiles().y + (y >> 5)) * grid.tiles().z + (z >> 5);
  const uint32_t bin = tile >> bins.bin_shift();
  const uint32_t entry = ((tile & ((1u << bins.bin_shift()) - 1)) << 15) |
                         CountGrid::LocalOffset(x & 31, y & 31, z & 31);
  walk::BinCursor& c = bins.cursors()[bin];
  if (c.tail == c.end) bins.Refill(bin);
  *c.tail++ = entry;
}

// Clustered points: a few hot tiles near the origin, the rest scattered over
// the far corner's 256^3 (at most 512 tiles, so the test stays small).
std::vector<Int3> ClusteredPoints(Int3 resolution, int points, uint64_t stream) {
  std::vector<Int3> out;
  Rng rng(7, stream);
  for (int i = 0; i < points; ++i) {
    const bool hot = (rng.Next() & 3) != 0;
    auto coord = [&](int n) {
      const int span = std::min(n, 256);
      return hot ? int(rng.Next() % 40) : n - span + int(rng.Next() % uint64_t(span));
    };
    const int x = coord(resolution.x), y = coord(resolution.y), z = coord(resolution.z);
    out.push_back({x, y, z});
  }
  return out;
}

// Every point of `sets` counted once in `grid`, and nothing else.
void ExpectCounts(const CountGrid& grid, const std::vector<std::vector<Int3>>& sets) {
  std::map<std::tuple<int, int, int>, uint32_t> want;
  uint64_t points = 0;
  for (const auto& set : sets)
    for (const Int3& v : set) ++want[{v.x, v.y, v.z}], ++points;
  for (const auto& [v, n] : want)
    ASSERT_EQ(grid.Get(std::get<0>(v), std::get<1>(v), std::get<2>(v)), n);
  EXPECT_EQ(grid.Total(), points);
}

void RunAndCompare(Int3 resolution, size_t capacity, int points) {
  CountGrid grid(resolution);
  TileBins bins(grid, capacity);
  const std::vector<Int3> set = ClusteredPoints(resolution, points, 1);
  for (const Int3& v : set) Push(bins, grid, v.x, v.y, v.z);
  bins.Flush();
  ExpectCounts(grid, {set});
}

TEST(TileBins, OneTilePerBin) {
  CountGrid grid({256, 256, 256});
  EXPECT_EQ(TileBins(grid, 1 << 16).bin_shift(), 0u);
  // A pool far smaller than the points: many flushes along the way.
  RunAndCompare({256, 256, 256}, 1 << 16, 500'000);
}

TEST(TileBins, ManyTilesPerBinOnLargeGrids) {
  // Over kSplitTiles tiles the walk bins by kBuckets runs of tiles: 2048^3
  // has 64^3 tiles, 1024 per bin, and 1024^3 128 per bin.
  CountGrid grid({2048, 2048, 2048});
  EXPECT_EQ(TileBins(grid, 1 << 16).bin_shift(), 10u);
  EXPECT_EQ(TileBins::BinCount({2048, 2048, 2048}), TileBins::kBuckets);
  EXPECT_EQ(TileBins::BinShift({1024, 1024, 1024}), 7u);
  EXPECT_EQ(TileBins::BinShift({512, 512, 512}), 0u);  // 4096 tiles: one per bin
  RunAndCompare({2048, 2048, 2048}, 1 << 16, 200'000);
}

TEST(TileBins, ABinLargerThanTheSplitPoolIsAppliedInParts) {
  // Two tiles of one bin take more entries than the second pass holds
  // (2^21), all in one flush.
  const Int3 res{1024, 1024, 1024};
  CountGrid grid(res);
  TileBins bins(grid, size_t{1} << 23);
  std::vector<Int3> set;
  for (int i = 0; i < 3'000'000; ++i) set.push_back({i % 7, (i / 7) % 5, 26 + i % 11});
  for (const Int3& v : set) Push(bins, grid, v.x, v.y, v.z);
  bins.Flush();
  ExpectCounts(grid, {set});
}

// Two threads' bins over one grid through SharedTiles, pushing and
// flushing at the same time (small pools: many flushes), count every point
// once, on a grid binned by tile and on one split in two passes.
TEST(TileBins, ThreadsSharingAGridCountEveryPoint) {
  for (const Int3 res : {Int3{256, 256, 256}, Int3{2048, 2048, 2048}}) {
    SCOPED_TRACE(res.x);
    CountGrid grid(res);
    SharedTiles shared(grid, uint32_t(TileBins::BinCount(res)));
    std::vector<std::vector<Int3>> sets;
    for (uint64_t t = 0; t < 2; ++t) sets.push_back(ClusteredPoints(res, 300'000, 10 + t));
    std::vector<std::thread> threads;
    for (uint32_t t = 0; t < 2; ++t)
      threads.emplace_back([&, t] {
        TileBins bins(shared, grid, 1 << 16, t * SharedTiles::kRanges / 2);
        for (const Int3& v : sets[t]) Push(bins, grid, v.x, v.y, v.z);
        bins.Flush();
      });
    for (std::thread& t : threads) t.join();
    EXPECT_FALSE(shared.overflowed());
    ExpectCounts(grid, sets);
  }
}

// Past the shared grid's tile limit increments are dropped (two threads
// must not share the grid's scratch tile) and the owner is told.
TEST(TileBins, ASharedGridPastItsTileLimitOverflows) {
  const Int3 res{256, 256, 256};
  CountGrid grid(res);
  grid.SetTileLimit(3);
  SharedTiles shared(grid, uint32_t(TileBins::BinCount(res)));
  TileBins bins(shared, grid, 1 << 16, 0);
  for (const Int3& v : ClusteredPoints(res, 10'000, 3)) Push(bins, grid, v.x, v.y, v.z);
  bins.Flush();
  EXPECT_TRUE(shared.overflowed());
  EXPECT_TRUE(bins.overflowed());
  EXPECT_EQ(grid.AllocatedTiles(), 3u);
}

TEST(TileBins, DirectModeHandsOutTheGridsTiles) {
  // Over kFlatVoxels, so direct mode goes through the table of tiles.
  const Int3 res{140, 128, 128};
  ASSERT_FALSE(TileBins::Flat(res));
  CountGrid grid(res);
  TileBins bins(grid, 1 << 16, /*direct=*/true);
  EXPECT_EQ(bins.flat(), nullptr);
  ASSERT_NE(bins.tiles(), nullptr);
  EXPECT_EQ(TileBins(grid, 1 << 16).tiles(), nullptr);  // binned: no table
  const uint32_t t = uint32_t(grid.TileCount() - 1);
  EXPECT_EQ(bins.tiles()[t], nullptr);
  uint32_t* counts = bins.Allocate(t);
  EXPECT_EQ(bins.tiles()[t], counts);
  EXPECT_EQ(grid.MutableTile(t), counts);
  ++counts[CountGrid::LocalOffset(1, 2, 3)];
  const Int3 o = grid.TileOrigin(t);
  EXPECT_EQ(grid.Get(o.x + 1, o.y + 2, o.z + 3), 1u);
  bins.Flush();  // nothing buffered
  EXPECT_EQ(grid.Total(), 1u);
  EXPECT_EQ(bins.MemoryBytes(), TileBins::Bytes(res, 1 << 16, true));
  EXPECT_LT(bins.MemoryBytes(), TileBins::Bytes(res, 1 << 16));
}

// Flat direct mode: counters indexed over the walk's lattice, added into
// the grid by Flush (a tile allocated only where a counter is not zero)
// and zeroed; a picture's rows fold as ImagePlane folds them.
TEST(TileBins, FlatModeAddsItsCountersIntoTheGrid) {
  for (const bool picture : {false, true}) {
    SCOPED_TRACE(picture ? "picture" : "volume");
    const Int3 lattice = picture ? Int3{300, 200, 1} : Int3{70, 40, 90};
    const Int3 res = picture ? FoldedImageResolution(300, 200) : lattice;
    const uint32_t fold = picture ? uint32_t(ImagePlane::kFoldShift) : 0;
    CountGrid grid(res), want(res);
    TileBins bins(grid, 1 << 16, /*direct=*/true, lattice, fold);
    ASSERT_NE(bins.flat(), nullptr);
    EXPECT_EQ(bins.tiles(), nullptr);
    EXPECT_EQ(bins.flat_discard(), uint32_t(lattice.x * lattice.y * lattice.z));
    Rng rng(5, 0);
    for (int round = 0; round < 2; ++round) {
      for (int i = 0; i < 20000; ++i) {
        // Clustered in a corner, so some tiles stay empty.
        const int x = int(rng.Next() % uint64_t(lattice.x / 2 + 1));
        const int y = int(rng.Next() % uint64_t(lattice.y));
        const int z = int(rng.Next() % uint64_t(lattice.z));
        ++bins.flat()[(x * lattice.y + y) * lattice.z + z];
        const Int3 v = picture ? ImagePlane::Voxel(x, y) : Int3{x, y, z};
        want.Add(v.x, v.y, v.z);
      }
      ++bins.flat()[bins.flat_discard()];  // the scratch counter is never added
      bins.Flush();
      EXPECT_EQ(grid.Total(), want.Total());
      EXPECT_EQ(grid.AllocatedTiles(), want.AllocatedTiles());
      EXPECT_LT(grid.AllocatedTiles(), grid.TileCount());
      for (uint64_t t = 0; t < grid.TileCount(); ++t) {
        const uint32_t *a = grid.TileOrNull(t), *b = want.TileOrNull(t);
        ASSERT_EQ(a == nullptr, b == nullptr) << t;
        if (a) {
          ASSERT_TRUE(std::equal(a, a + CountGrid::kTileVoxels, b)) << t;
        }
      }
      for (uint32_t i = 0; i < bins.flat_discard(); ++i) ASSERT_EQ(bins.flat()[i], 0u) << i;
    }
    EXPECT_EQ(bins.MemoryBytes(), TileBins::Bytes(lattice, 1 << 16, true));
  }
}

// CountGrid's tiles come from a TileArena: zeroed, distinct, and spread over
// several 2 MiB blocks once there are more than 16.
TEST(TileArena, HandsOutZeroedDistinctTiles) {
  constexpr size_t kBytes = CountGrid::kTileVoxels * sizeof(uint32_t);
  TileArena arena(kBytes);
  std::vector<uint32_t*> tiles;
  for (int i = 0; i < 40; ++i) {
    auto* t = static_cast<uint32_t*>(arena.Allocate());
    ASSERT_EQ(uintptr_t(t) % kBytes, 0u);  // blocks are 2 MiB aligned
    EXPECT_TRUE(std::all_of(t, t + CountGrid::kTileVoxels, [](uint32_t v) { return v == 0; }));
    std::fill(t, t + CountGrid::kTileVoxels, uint32_t(i + 1));
    tiles.push_back(t);
  }
  for (int i = 0; i < 40; ++i) EXPECT_EQ(tiles[size_t(i)][CountGrid::kTileVoxels - 1], i + 1u);
  // Moving a grid moves its arena: the tiles stay valid, nothing is freed twice.
  CountGrid a({256, 256, 256});
  for (int x = 0; x < 256; x += 32) a.Add(x, 5, 7, 3);
  CountGrid b = std::move(a);
  a = CountGrid({64, 64, 64});
  a.Add(1, 1, 1);
  EXPECT_EQ(b.Total(), 24u);
  EXPECT_EQ(b.Get(224, 5, 7), 3u);
  EXPECT_EQ(a.Total(), 1u);
}

TEST(TileBins, MemoryIsFixedAndPredicted) {
  CountGrid grid({512, 300, 70});
  TileBins bins(grid, 1 << 20);
  EXPECT_EQ(bins.MemoryBytes(), TileBins::Bytes({512, 300, 70}, 1 << 20));
  EXPECT_GE(bins.MemoryBytes(), (uint64_t{1} << 20) * sizeof(uint32_t));
}

}  // namespace
}  // namespace nimbus
