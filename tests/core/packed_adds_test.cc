// KeyBins' packed loops (core/chaos/packed_adds.h) at every SIMD level the
// CPU has: the same keys held in the same order, the same words after the
// adds, the same tiles reported, weighted or not.
#include <gtest/gtest.h>

#include <bit>
#include <vector>

#include "core/base/random.h"
#include "core/chaos/packed_adds.h"
#include "core/grid/count_grid.h"

namespace nimbus {
namespace {

constexpr uint64_t kTiles = 32;  // the most KeyBins packs

// A round's keys: voxels over `tiles` tiles (some rounds all in one
// voxel, so adds to one word follow each other), colours, and weights
// when `weighted`.
std::vector<uint64_t> RoundKeys(Rng& rng, uint64_t tiles, bool weighted, bool one_voxel) {
  std::vector<uint64_t> keys(64);
  const uint64_t fixed = rng.Next() % (tiles << 15);
  for (uint64_t& k : keys) {
    k = CountGrid::WithColor(one_voxel ? fixed : rng.Next() % (tiles << 15),
                             uint32_t(rng.Next() % 65536));
    if (weighted) k = CountGrid::WithWeight(k, uint32_t(1 + rng.Next() % 64));
  }
  return keys;
}

struct Outcome {
  std::vector<uint64_t> words, held;
  std::vector<uint32_t> counts;
  uint64_t touched = 0;
};

// 3000 rounds through `loops`: lanes random, none, all or one.
Outcome Drive(const packed::Loops& loops, bool weighted, uint64_t seed) {
  Rng rng(seed, 0);
  Outcome run;
  run.words.assign(kTiles * CountGrid::kTileVoxels, 0);
  alignas(64) uint64_t hold[packed::kHoldRoom];
  for (int r = 0; r < 3000; ++r) {
    const uint64_t tiles = r % 5 == 0 ? 1 : kTiles;
    const std::vector<uint64_t> keys = RoundKeys(rng, tiles, weighted, r % 11 == 0);
    const uint64_t pick = rng.Next();
    const uint64_t lanes = r % 13 == 0   ? 0
                           : r % 13 == 1 ? ~uint64_t{0}
                           : r % 13 == 2 ? uint64_t{1} << (pick % 64)
                                         : pick;
    const uint32_t n = loops.hold(run.words.data(), keys.data(), lanes, hold);
    EXPECT_EQ(n, uint32_t(std::popcount(lanes)));
    run.counts.push_back(n);
    run.held.insert(run.held.end(), hold, hold + n);
    run.touched |= loops.apply(run.words.data(), hold, n, weighted);
  }
  return run;
}

// What the adds must give: each key's weight on its count (bits 40 up) and
// weight times its colour on its sum, and the tile of every key.
Outcome Expected(bool weighted, uint64_t seed) {
  Outcome run = Drive(packed::LoopsFor(SimdLevel::kScalar), weighted, seed);
  std::vector<uint64_t> words(run.words.size(), 0);
  uint64_t touched = 0;
  for (uint64_t k : run.held) {
    const uint64_t w = weighted ? CountGrid::WeightOf(k) : 1;
    const uint64_t v = k & CountGrid::kVoxelMask;
    words[v] += (w << 40) + w * (k >> CountGrid::kColorShift);
    touched |= uint64_t{1} << (v >> 15);
  }
  EXPECT_TRUE(words == run.words);
  EXPECT_EQ(touched, run.touched);
  return run;
}

TEST(PackedAdds, EveryLevelAddsWhatTheScalarLoopsAdd) {
  for (bool weighted : {false, true}) {
    SCOPED_TRACE(weighted ? "weighted" : "unweighted");
    const Outcome want = Expected(weighted, 41);
    for (SimdLevel level : {SimdLevel::kScalar, SimdLevel::kAvx2, SimdLevel::kAvx512}) {
      if (level > DetectSimd()) continue;
      SCOPED_TRACE(std::string(SimdName(level)));
      const Outcome got = Drive(packed::LoopsFor(level), weighted, 41);
      EXPECT_TRUE(got.held == want.held);  // same keys, lane order
      EXPECT_TRUE(got.counts == want.counts);
      EXPECT_TRUE(got.words == want.words);
      EXPECT_EQ(got.touched, want.touched);
    }
  }
}

}  // namespace
}  // namespace nimbus
