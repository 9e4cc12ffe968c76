// Sharded chaos games (docs/sharding.md): the chunk ranges of S shards,
// each saved as a partial file and added back in shard order, give exactly
// the counts, colour sums and counters of the whole run.
#include <gtest/gtest.h>

#include <string>
#include <vector>

#include "core/chaos/chaos_game.h"
#include "core/chaos/chaos_partial.h"
#include "tests/support/attractors.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

struct RangeRun {
  CountGrid counts;
  ChaosGameStats stats;
};

RangeRun RunRange(ChaosGameParams p, uint64_t begin, uint64_t end, int threads) {
  p.chunk_begin = begin;
  p.chunk_end = end;
  auto game = ChaosGame::Create(p, threads);
  EXPECT_TRUE(game.ok()) << game.status();
  EXPECT_TRUE((*game)->Run(nullptr).ok());
  EXPECT_TRUE((*game)->done());
  ChaosGameStats stats = (*game)->stats();
  return {(*game)->TakeCounts(), stats};
}

void ExpectSame(const CountGrid& a, const CountGrid& b) {
  const Int3 r = a.resolution();
  uint64_t differing = 0;
  for (int x = 0; x < r.x; ++x)
    for (int y = 0; y < r.y; ++y)
      for (int z = 0; z < r.z; ++z)
        differing += a.Get(x, y, z) != b.Get(x, y, z) ||
                     a.GetColorSum(x, y, z) != b.GetColorSum(x, y, z);
  EXPECT_EQ(differing, 0u);
  EXPECT_EQ(a.Total(), b.Total());
}

// S shards, each on its own thread count and through a partial file, add
// up to `whole`.
void ExpectShardsSumTo(const ChaosGameParams& p, const RangeRun& whole, uint32_t shards) {
  SCOPED_TRACE(shards);
  testing::TempDir dir;
  CountGrid sum(p.frame.resolution, p.color.mode != ColorMode::kNone);
  ChaosGameStats stats;
  uint64_t next = 0;
  for (uint32_t k = 0; k < shards; ++k) {
    const auto [begin, end] = ChaosGame::ShardChunks(p.iterations, shards, k);
    EXPECT_EQ(begin, next);  // the shards tile the run in order
    next = end;
    const RangeRun part = RunRange(p, begin, end, 1 + int(k % 2));
    const auto path = dir / ("shard-" + std::to_string(k));
    ASSERT_TRUE(SaveChaosPartial(path, part.counts, part.stats).ok());
    ASSERT_TRUE(AddChaosPartialFile(path, sum, stats).ok());
  }
  EXPECT_EQ(next, ChaosGame::NumChunks(p.iterations));
  ExpectSame(sum, whole.counts);
  EXPECT_EQ(stats.iterations_done, whole.stats.iterations_done);
  EXPECT_EQ(stats.iterations_done, p.iterations);
  EXPECT_EQ(stats.outside, whole.stats.outside);
  EXPECT_EQ(stats.reseeded, whole.stats.reseeded);
  EXPECT_EQ(stats.final_nonfinite, whole.stats.final_nonfinite);
}

void ExpectShardsSumToTheWhole(const ChaosGameParams& p, std::vector<uint32_t> shard_counts) {
  const RangeRun whole = RunRange(p, 0, 0, 2);
  for (uint32_t shards : shard_counts) ExpectShardsSumTo(p, whole, shards);
}

TEST(ChaosShard, ShardChunksTileTheRun) {
  const uint64_t it = 10 * ChaosGame::kChunkIterations + 5;  // 11 chunks
  EXPECT_EQ(ChaosGame::ShardChunks(it, 3, 0), std::make_pair(uint64_t{0}, uint64_t{3}));
  EXPECT_EQ(ChaosGame::ShardChunks(it, 3, 1), std::make_pair(uint64_t{3}, uint64_t{7}));
  EXPECT_EQ(ChaosGame::ShardChunks(it, 3, 2), std::make_pair(uint64_t{7}, uint64_t{11}));
  EXPECT_EQ(ChaosGame::ShardChunks(it, 1, 0), std::make_pair(uint64_t{0}, uint64_t{11}));
}

TEST(ChaosShard, FastPathRangesSumToTheWholeRun) {
  ExpectShardsSumToTheWhole(SierpinskiTetrahedronParams(64, 7 * ChaosGame::kChunkIterations + 99),
                            {3, 7});
}

TEST(ChaosShard, ColourAndSplatRangesSumToTheWholeRun) {
  ChaosGameParams p = OctantCloudParams(32, 4 * ChaosGame::kChunkIterations + 1234);
  for (size_t i = 0; i < p.ifs.maps.size(); ++i) p.ifs.maps[i].color = double(i) / 7;
  p.color.mode = ColorMode::kMap;
  p.color.blend = 0.3;
  p.splat = true;
  ExpectShardsSumToTheWhole(p, {1, 3, 5});
}

TEST(ChaosShard, ARangeOutsideTheRunIsRefused) {
  ChaosGameParams p = SierpinskiTetrahedronParams(16, 2 * ChaosGame::kChunkIterations);
  p.chunk_begin = 1;
  p.chunk_end = 3;
  EXPECT_EQ(ChaosGame::Create(p, 1).status().code(), absl::StatusCode::kInvalidArgument);
}

TEST(ChaosShard, ADamagedPartialIsRefused) {
  const RangeRun part = RunRange(SierpinskiTetrahedronParams(16, 1000), 0, 0, 1);
  testing::TempDir dir;
  ASSERT_TRUE(SaveChaosPartial(dir / "p", part.counts, part.stats).ok());
  std::string bytes;
  {
    CountGrid sum({16, 16, 16});
    ChaosGameStats stats;
    ASSERT_TRUE(AddChaosPartialFile(dir / "p", sum, stats).ok());
    EXPECT_EQ(sum.Total(), part.counts.Total());
  }
  FILE* f = std::fopen((dir / "p").c_str(), "r+b");
  std::fseek(f, 100, SEEK_SET);
  std::fputc(0x5a, f);
  std::fclose(f);
  CountGrid sum({16, 16, 16});
  ChaosGameStats stats;
  EXPECT_EQ(AddChaosPartialFile(dir / "p", sum, stats).code(), absl::StatusCode::kDataLoss);
  CountGrid other({16, 16, 8});
  ASSERT_TRUE(SaveChaosPartial(dir / "q", part.counts, part.stats).ok());
  EXPECT_EQ(AddChaosPartialFile(dir / "q", other, stats).code(),
            absl::StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace nimbus
