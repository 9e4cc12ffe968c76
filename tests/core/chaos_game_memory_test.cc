// Memory of huge sparse chaos-game jobs: the pilot census that sizes them
// before they start, and the budget that stops a run which outgrows it.
#include <gtest/gtest.h>

#include "tests/support/attractors.h"
#include "core/chaos/chaos_game.h"

namespace nimbus {
namespace {

size_t MaxTilesPerThread(const ChaosGameParams& params, int threads) {
  auto game = ChaosGame::Create(params, threads);
  EXPECT_TRUE(game.ok()) << game.status();
  EXPECT_TRUE((*game)->Run(nullptr).ok());
  size_t tiles = 0;
  for (const CountGrid& g : (*game)->partial_counts()) tiles = std::max(tiles, g.AllocatedTiles());
  return tiles;
}

TEST(ChaosGamePilot, EstimateCoversTheTilesARealRunTouches) {
  struct Case {
    const char* name;
    ChaosGameParams params;
  };
  std::vector<Case> cases = {
      {"sierpinski 512^3", SierpinskiTetrahedronParams(512, uint64_t{1} << 25)},
      {"octant 256^3", OctantCloudParams(256, uint64_t{1} << 24)},
      {"fern 512^3", FernVolumeParams(512, uint64_t{1} << 25)},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    auto census = ChaosGame::Pilot(c.params, uint64_t{1} << 21, nullptr);
    ASSERT_TRUE(census.ok()) << census.status();
    EXPECT_EQ(census->samples, uint64_t{1} << 21);
    EXPECT_GT(census->seen, 0u);
    EXPECT_GE(census->estimate, census->seen);
    EXPECT_GE(census->estimate, MaxTilesPerThread(c.params, 2));
  }
}

TEST(ChaosGamePilot, ThinAttractorAt2048IsSizedByWhatItTouches) {
  // The tetrahedron's bounding ball covers nearly the whole 2048^3 grid, so
  // the geometric bound is tens of GiB; the attractor, of dimension 2,
  // touches a few percent of the tiles.
  const ChaosGameParams params = SierpinskiTetrahedronParams(2048, 100'000'000);
  const ChaosGameMemory geometric = ChaosGame::EstimateMemory(params, 2, 4);
  EXPECT_GT(geometric.peak(), uint64_t{32} << 30);
  auto census = ChaosGame::Pilot(params, uint64_t{1} << 21, nullptr);
  ASSERT_TRUE(census.ok());
  const uint64_t all_tiles = 64 * 64 * 64;
  EXPECT_LT(census->estimate, all_tiles / 8);
  const ChaosGameMemory piloted = ChaosGame::EstimateMemory(params, 2, 4, census->estimate);
  EXPECT_LT(piloted.peak(), uint64_t{8} << 30);
  // A hint never raises the estimate above the geometric bound.
  EXPECT_EQ(ChaosGame::EstimateMemory(params, 2, 4, all_tiles * 10).peak(), geometric.peak());
}

// Binned fast-path threads share one grid, so two threads are priced at
// about one grid, not two, and still cover what a real run allocates.
TEST(ChaosGamePilot, SharedGridIsPricedOnce) {
  ChaosGameParams params = FernVolumeParams(1024, uint64_t{1} << 24);
  auto census = ChaosGame::Pilot(params, uint64_t{1} << 21, nullptr);
  ASSERT_TRUE(census.ok());
  ASSERT_GT(census->estimate, 256u);  // binned, so shared
  const uint64_t one = ChaosGame::EstimateMemory(params, 1, 4, census->estimate).accumulation;
  const uint64_t two = ChaosGame::EstimateMemory(params, 2, 4, census->estimate).accumulation;
  params.shared_grid = false;
  const uint64_t apart = ChaosGame::EstimateMemory(params, 2, 4, census->estimate).accumulation;
  EXPECT_LT(two, apart);
  EXPECT_LT(two - one, (apart - one) / 2);
  params.shared_grid.reset();
  auto game = ChaosGame::Create(params, 2);
  ASSERT_TRUE(game.ok()) << game.status();
  ASSERT_TRUE((*game)->Run(nullptr).ok());
  EXPECT_EQ((*game)->partial_counts().size(), 1u);
  EXPECT_LE((*game)->MemoryBytes(), two);
}

TEST(ChaosGamePilot, SplattingGrowsTheEstimateByTheNeighbouringTiles) {
  ChaosGameParams params = SierpinskiTetrahedronParams(512, uint64_t{1} << 22);
  auto plain = ChaosGame::Pilot(params, uint64_t{1} << 20, nullptr);
  params.splat = true;
  auto splat = ChaosGame::Pilot(params, uint64_t{1} << 20, nullptr);
  ASSERT_TRUE(plain.ok() && splat.ok());
  EXPECT_EQ(plain->seen, splat->seen);
  EXPECT_GT(splat->estimate, plain->estimate);
  EXPECT_GE(splat->estimate, MaxTilesPerThread(params, 1));
}

TEST(ChaosGameBudget, ARunThatOutgrowsItsBudgetStopsCleanly) {
  // A volume-filling cloud at 512^3 touches all 4096 tiles (512 MiB per
  // thread); a 64 MiB budget must stop it without allocating past it.
  ChaosGameParams params = OctantCloudParams(512, uint64_t{1} << 24);
  params.memory_budget = uint64_t{64} << 20;
  auto game = ChaosGame::Create(params, 2);
  ASSERT_TRUE(game.ok());
  const absl::Status st = (*game)->Run(nullptr);
  EXPECT_TRUE(absl::IsResourceExhausted(st)) << st;
  EXPECT_NE(st.message().find("memory budget"), std::string_view::npos);
  EXPECT_LE((*game)->MemoryBytes(), params.memory_budget + (uint64_t{1} << 20));
  // The same job within budget runs to the end.
  params.memory_budget = uint64_t{2} << 30;
  params.iterations = uint64_t{1} << 22;
  auto ok_game = ChaosGame::Create(params, 2);
  ASSERT_TRUE(ok_game.ok());
  EXPECT_TRUE((*ok_game)->Run(nullptr).ok());
}

TEST(ChaosGameBudget, ColourGridsStopCleanlyToo) {
  ChaosGameParams params = OctantCloudParams(512, uint64_t{1} << 23);
  params.color.mode = ColorMode::kAddress;  // the general path, 12 bytes a voxel
  params.memory_budget = uint64_t{96} << 20;
  auto game = ChaosGame::Create(params, 1);
  ASSERT_TRUE(game.ok());
  EXPECT_TRUE(absl::IsResourceExhausted((*game)->Run(nullptr)));
  EXPECT_LE((*game)->MemoryBytes(), params.memory_budget + (uint64_t{2} << 20));
}

}  // namespace
}  // namespace nimbus
