// KeyBins (core/chaos/key_bins.h): binned keys add up to exactly what
// adding each key directly gives, counts and colour sums, weighted or not,
// through pool flushes and on grids whose bins hold several tiles.
#include <gtest/gtest.h>

#include <vector>

#include "core/base/random.h"
#include "core/chaos/key_bins.h"
#include "core/grid/count_grid.h"

namespace nimbus {
namespace {

// Random keys, mostly in a corner of a few tiles and a few anywhere (few
// enough to keep the tiles allocated small), each with a colour and, when
// `weighted`, a weight.
std::vector<uint64_t> RandomKeys(const CountGrid& grid, size_t n, bool weighted, Rng& rng) {
  const Int3 r = grid.resolution();
  std::vector<uint64_t> keys;
  for (size_t i = 0; i < n; ++i) {
    const bool anywhere = rng.Next() % 2000 == 0;
    const int x = int(rng.Next() % uint64_t(anywhere ? r.x : std::min(r.x, 70)));
    const int y = int(rng.Next() % uint64_t(anywhere ? r.y : std::min(r.y, 40)));
    const int z = int(rng.Next() % uint64_t(r.z));
    uint64_t key = CountGrid::WithColor(grid.Key(x, y, z), uint32_t(rng.Next() % 65536));
    if (weighted) key = CountGrid::WithWeight(key, uint32_t(1 + rng.Next() % 64));
    keys.push_back(key);
  }
  return keys;
}

void ExpectSameGrids(const CountGrid& a, const CountGrid& b) {
  ASSERT_EQ(a.AllocatedTiles(), b.AllocatedTiles());
  std::vector<std::vector<uint64_t>> ta, tb;
  a.ForEachTileWithColor([&](Int3, const uint32_t* t, const uint64_t* c) {
    ta.emplace_back(t, t + CountGrid::kTileVoxels);
    if (c) ta.emplace_back(c, c + CountGrid::kTileVoxels);
  });
  b.ForEachTileWithColor([&](Int3, const uint32_t* t, const uint64_t* c) {
    tb.emplace_back(t, t + CountGrid::kTileVoxels);
    if (c) tb.emplace_back(c, c + CountGrid::kTileVoxels);
  });
  EXPECT_TRUE(ta == tb);
}

struct Shape {
  Int3 resolution;
  bool color, weighted;
};

TEST(KeyBins, AddsUpToDirectAdds) {
  // A 3D grid, a folded 2D one, and one with more tiles than bins.
  const Shape shapes[] = {{{200, 150, 90}, true, false},
                          {{200, 150, 90}, false, true},
                          {{1024, 1024, 1}, true, true},
                          {{2048, 2048, 320}, true, false},
                          {{2048, 2048, 320}, false, false}};
  Rng rng(11, 0);
  for (const Shape& s : shapes) {
    SCOPED_TRACE(testing::Message() << s.resolution.x << "x" << s.resolution.y << "x"
                                    << s.resolution.z << " color " << s.color << " weighted "
                                    << s.weighted);
    CountGrid direct(s.resolution, s.color), binned(s.resolution, s.color);
    // A pool far smaller than the keys: many flushes, some mid-refill.
    KeyBins bins(binned, 1 << 12, s.weighted);
    const std::vector<uint64_t> keys = RandomKeys(direct, 100000, s.weighted, rng);
    for (uint64_t key : keys) {
      direct.AddKey(s.color ? key : key & ~(uint64_t{0xffff} << CountGrid::kColorShift));
      bins.Add(s.color ? key : key & ~(uint64_t{0xffff} << CountGrid::kColorShift));
    }
    bins.Flush();
    ExpectSameGrids(direct, binned);
    EXPECT_LE(bins.MemoryBytes(), KeyBins::Bytes(s.resolution, 1 << 12));
  }
}

}  // namespace
}  // namespace nimbus
