// KeyBins (core/chaos/key_bins.h): binned keys add up to exactly what
// adding each key directly gives, counts and colour sums, weighted or not,
// through pool flushes and on grids whose bins hold several tiles.
#include <gtest/gtest.h>

#include <bit>
#include <mutex>
#include <thread>
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
    EXPECT_LE(bins.MemoryBytes(), KeyBins::Bytes(s.resolution, 1 << 12, s.color));
  }
}

// Packed grids (KeyBins::Packs: small, with colour) take every key through
// the packed words: keys added a round at a time with AddLanes (random
// lane masks, empty ones included) and one at a time with Add, flushed in
// the middle and at the end, must leave the grid as adding each key
// directly does.
TEST(KeyBins, PackedWordsAddUpToDirectAdds) {
  const Shape shapes[] = {{{1024, 1024, 1}, true, false},
                          {{1024, 1024, 1}, true, true},
                          {{64, 64, 64}, true, false},
                          {{20, 30, 40}, true, true}};
  Rng rng(12, 0);
  for (const Shape& s : shapes) {
    SCOPED_TRACE(testing::Message() << s.resolution.x << "x" << s.resolution.y << "x"
                                    << s.resolution.z << " weighted " << s.weighted);
    CountGrid direct(s.resolution, true), packed(s.resolution, true);
    KeyBins bins(packed, 1 << 16, s.weighted);
    ASSERT_TRUE(bins.packed());
    const std::vector<uint64_t> keys = RandomKeys(direct, 64 * 3000, s.weighted, rng);
    for (uint64_t key : keys) direct.AddKey(key);
    for (size_t i = 0; i < keys.size(); i += 64) {
      // Round 1000 adds its keys one by one; the others a random subset
      // now and the rest as a second call (some rounds add nothing).
      if (i / 64 == 1000) {
        for (size_t k = i; k < i + 64; ++k) bins.Add(keys[k]);
        continue;
      }
      const uint64_t lanes = i / 64 % 7 == 0 ? 0 : rng.Next();
      EXPECT_EQ(bins.AddLanes(keys.data() + i, lanes), uint64_t(std::popcount(lanes)));
      bins.AddLanes(keys.data() + i, ~lanes);
      if (i / 64 == 1500) bins.Flush();  // a preview's flush mid-run
    }
    bins.Flush();
    ExpectSameGrids(direct, packed);
    EXPECT_EQ(bins.MemoryBytes(), KeyBins::Bytes(s.resolution, 1 << 16, true));
  }
}

// A flame round of 256 walkers hands over its landed lanes as four mask
// words in one call, packed (the round's keys held together) or binned:
// random words, empty and full ones among them, then the complements.
TEST(KeyBins, ARoundOfSeveralMaskWordsAddsUpToDirectAdds) {
  const Shape shapes[] = {{{1024, 1024, 1}, true, false}, {{64, 64, 64}, false, true}};
  Rng rng(14, 0);
  for (const Shape& s : shapes) {
    SCOPED_TRACE(testing::Message() << s.resolution.x << "x" << s.resolution.y);
    CountGrid direct(s.resolution, s.color), bins_grid(s.resolution, s.color);
    KeyBins bins(bins_grid, 1 << 16, s.weighted);
    EXPECT_EQ(bins.packed(), s.color);
    const std::vector<uint64_t> keys = RandomKeys(direct, 256 * 800, s.weighted, rng);
    for (uint64_t key : keys) direct.AddKey(key);
    for (size_t i = 0; i < keys.size(); i += 256) {
      uint64_t lanes[4], rest[4];
      uint64_t want = 0;
      for (int w = 0; w < 4; ++w) {
        const uint64_t r = rng.Next();
        lanes[w] = r % 5 == 0 ? 0 : r % 5 == 1 ? ~uint64_t{0} : rng.Next();
        rest[w] = ~lanes[w];
        want += uint64_t(std::popcount(lanes[w]));
      }
      const int words = i / 256 % 9 == 0 ? 3 : 4;  // a short round: its keys, less the last word's
      if (words == 3) {
        for (size_t k = i + 192; k < i + 256; ++k) bins.Add(keys[k]);
        want -= uint64_t(std::popcount(lanes[3]));
      }
      EXPECT_EQ(bins.AddLanes(keys.data() + i, lanes, words), want);
      bins.AddLanes(keys.data() + i, rest, words);
    }
    bins.Flush();
    ExpectSameGrids(direct, bins_grid);
  }
}

// Two threads' packed words folding into one grid under a shared lock
// (a picture job's workers) add up to the direct adds of all their keys,
// with flushes in the middle on both.
TEST(KeyBins, PackedThreadsShareOneGrid) {
  const Int3 res{1024, 1024, 1};
  CountGrid direct(res, true), shared(res, true);
  Rng rng(13, 0);
  const std::vector<uint64_t> keys = RandomKeys(direct, 64 * 4000, false, rng);
  for (uint64_t key : keys) direct.AddKey(key);
  std::mutex lock;
  auto run = [&](size_t first) {
    KeyBins bins(shared, 1 << 16, false, &lock);
    for (size_t i = first; i < keys.size(); i += 128) {
      bins.AddLanes(keys.data() + i, ~uint64_t{0});
      if (i % (128 * 500) == first) bins.Flush();
    }
    bins.Flush();
  };
  std::thread a(run, 0), b(run, 64);
  a.join();
  b.join();
  ExpectSameGrids(direct, shared);
}

// Without colour, or on grids larger than a megapixel picture, keys stay
// binned.
TEST(KeyBins, OnlySmallColourGridsPack) {
  EXPECT_TRUE(KeyBins::Packs({1024, 1024, 1}, true));
  EXPECT_FALSE(KeyBins::Packs({1024, 1024, 1}, false));
  EXPECT_FALSE(KeyBins::Packs({2048, 1024, 1}, true));
  EXPECT_FALSE(KeyBins::Packs({256, 256, 256}, true));
  CountGrid grid({1024, 1024, 1}, false);
  EXPECT_FALSE(KeyBins(grid, 1 << 16, false).packed());
}

// A packed word holds at most 2^24 - 1 visits: a voxel hit 2^24 times and
// more (weight 64 keys, 19.7 million visits) must be folded into the grid
// on the way and end with the exact count and colour sum, as must a voxel
// hit once beside it.
TEST(KeyBins, PackedWordsFoldBeforeTheyOverflow) {
  const Int3 res{1024, 1024, 1};
  CountGrid direct(res, true), packed(res, true);
  KeyBins bins(packed, 1 << 16, /*weighted=*/true);
  const uint64_t hot = CountGrid::WithWeight(CountGrid::WithColor(packed.Key(5, 6, 0), 65535), 64);
  const uint64_t cold = CountGrid::WithColor(packed.Key(900, 1000, 0), 77);
  std::vector<uint64_t> round(64, hot);
  round[63] = cold;
  for (int r = 0; r < 5000; ++r) {
    bins.AddLanes(round.data(), ~uint64_t{0});
    for (uint64_t key : round) direct.AddKey(key);
  }
  bins.Flush();
  EXPECT_EQ(packed.Get(5, 6, 0), 5000u * 63 * 64);
  EXPECT_EQ(packed.GetColorSum(5, 6, 0), uint64_t{5000} * 63 * 64 * 65535);
  EXPECT_EQ(packed.GetColorSum(900, 1000, 0), uint64_t{5000} * 77);
  ExpectSameGrids(direct, packed);
}

// No keys, or only empty lane masks: a flush allocates no tile.
TEST(KeyBins, PackedEmptyFlushAllocatesNothing) {
  CountGrid grid({1024, 1024, 1}, true);
  KeyBins bins(grid, 1 << 16, false);
  const std::vector<uint64_t> keys(64, grid.Key(1, 2, 0));
  bins.Flush();
  EXPECT_EQ(bins.AddLanes(keys.data(), 0), 0u);
  bins.Flush();
  EXPECT_EQ(grid.AllocatedTiles(), 0u);
  EXPECT_EQ(grid.Total(), 0u);
}

// Past a grid's tile limit the fold lands in the scratch tile and flags the
// overflow, as the binned flush does.
TEST(KeyBins, PackedFoldRespectsTheTileLimit) {
  CountGrid grid({1024, 1024, 1}, true);
  grid.SetTileLimit(1);
  KeyBins bins(grid, 1 << 16, false);
  std::vector<uint64_t> keys(64, grid.Key(1, 2, 0));
  keys[1] = grid.Key(1000, 2, 0);  // another tile
  bins.AddLanes(keys.data(), 3);
  EXPECT_FALSE(grid.overflowed());  // held, not yet added
  bins.Flush();
  EXPECT_TRUE(grid.overflowed());
  EXPECT_EQ(grid.AllocatedTiles(), 1u);
}

}  // namespace
}  // namespace nimbus
