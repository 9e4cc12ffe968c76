// TileBins: increments binned by tile as they are produced, applied on
// flush, including pool exhaustion and bins that hold several tiles.
#include "core/chaos/tile_bins.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <map>
#include <tuple>

#include "core/base/random.h"

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

void RunAndCompare(Int3 resolution, size_t capacity, int points) {
  CountGrid grid(resolution);
  TileBins bins(grid, capacity);
  std::map<std::tuple<int, int, int>, uint32_t> want;
  Rng rng(7, 1);
  for (int i = 0; i < points; ++i) {
    // Clustered: a few hot tiles near the origin, the rest scattered over
    // the far corner's 256^3 (at most 512 tiles, so the test stays small).
    const bool hot = (rng.Next() & 3) != 0;
    auto coord = [&](int n) {
      const int span = std::min(n, 256);
      return hot ? int(rng.Next() % 40) : n - span + int(rng.Next() % uint64_t(span));
    };
    const int x = coord(resolution.x), y = coord(resolution.y), z = coord(resolution.z);
    Push(bins, grid, x, y, z);
    ++want[{x, y, z}];
  }
  bins.Flush();
  uint64_t total = 0;
  for (const auto& [v, n] : want) {
    ASSERT_EQ(grid.Get(std::get<0>(v), std::get<1>(v), std::get<2>(v)), n);
    total += n;
  }
  EXPECT_EQ(grid.Total(), total);
  EXPECT_EQ(total, uint64_t(points));
}

TEST(TileBins, OneTilePerBin) {
  CountGrid grid({256, 256, 256});
  EXPECT_EQ(TileBins(grid, 1 << 16).bin_shift(), 0u);
  // A pool far smaller than the points: many flushes along the way.
  RunAndCompare({256, 256, 256}, 1 << 16, 500'000);
}

TEST(TileBins, SeveralTilesPerBinOnHugeGrids) {
  // 2048^3 has 64^3 tiles, eight per bin.
  CountGrid grid({2048, 2048, 2048});
  EXPECT_EQ(TileBins(grid, 1 << 16).bin_shift(), 3u);
  RunAndCompare({2048, 2048, 2048}, 1 << 16, 200'000);
}

TEST(TileBins, MemoryIsFixedAndPredicted) {
  CountGrid grid({512, 300, 70});
  TileBins bins(grid, 1 << 20);
  EXPECT_EQ(bins.MemoryBytes(), TileBins::Bytes({512, 300, 70}, 1 << 20));
  EXPECT_GE(bins.MemoryBytes(), (uint64_t{1} << 20) * sizeof(uint32_t));
}

}  // namespace
}  // namespace nimbus
