#include "core/chaos/chaos_game.h"

#include <gtest/gtest.h>

#include <cmath>

namespace nimbus {
namespace {

// The four maps z/2 + {0, 1/2, i/2, (1+i)/2} of docs/algorithms.md#probabilities-and-the-measure-attractor, in
// the z = 0 plane, with p = (0.30, 0.20, 0.25, 0.25).
ChaosGameParams SquareMeasure(uint64_t iterations, uint64_t seed) {
  ChaosGameParams p;
  const Vec3 offsets[4] = {{0, 0, 0}, {0.5, 0, 0}, {0, 0.5, 0}, {0.5, 0.5, 0}};
  for (const Vec3& o : offsets) {
    PointMap m;
    m.pre = Affine3::Translate(o) * Affine3::Scale({0.5, 0.5, 0.5});
    p.ifs.maps.push_back(m);
  }
  p.ifs.probabilities = {0.30, 0.20, 0.25, 0.25};
  p.frame.resolution = {64, 64, 1};
  p.frame.bounds = {{0, 0, -0.5}, {1, 1, 0.5}};
  p.iterations = iterations;
  p.seed = seed;
  return p;
}

CountGrid RunGame(ChaosGameParams params, int threads) {
  auto game = ChaosGame::Create(std::move(params), threads);
  EXPECT_TRUE(game.ok()) << game.status();
  EXPECT_TRUE((*game)->Run(nullptr).ok());
  return (*game)->TakeCounts();
}

// Exact measure: the mass of the dyadic cell with address (a1..ak) is
// p_a1 * ... * p_ak. The cell of a point is fixed by the last k maps drawn,
// so samples decorrelate after k steps; we allow 6 standard deviations of a
// binomial estimate with N/k effective samples.
TEST(ChaosGame, SquareMeasureMatchesProductsOfProbabilities) {
  const uint64_t n = uint64_t{1} << 24;
  const CountGrid counts = RunGame(SquareMeasure(n, 7), 2);
  ASSERT_EQ(counts.Total(), n);
  const double p[4] = {0.30, 0.20, 0.25, 0.25};
  for (int depth = 1; depth <= 3; ++depth) {
    const int cells = 1 << depth, size = 64 / cells;
    for (int cx = 0; cx < cells; ++cx) {
      for (int cy = 0; cy < cells; ++cy) {
        uint64_t mass = 0;
        for (int x = cx * size; x < (cx + 1) * size; ++x)
          for (int y = cy * size; y < (cy + 1) * size; ++y) mass += counts.Get(x, y, 0);
        // Address digits, most significant first: bit 1 of x/y at each level.
        double expected = 1;
        for (int level = depth - 1; level >= 0; --level) {
          const int ax = (cx >> level) & 1, ay = (cy >> level) & 1;
          expected *= p[ax + 2 * ay];
        }
        const double measured = double(mass) / n;
        const double sigma = std::sqrt(expected * (1 - expected) / (double(n) / depth));
        EXPECT_NEAR(measured, expected, 6 * sigma)
            << "depth " << depth << " cell (" << cx << "," << cy << ")";
      }
    }
  }
}

TEST(ChaosGame, UniformProbabilitiesGiveUniformDensity) {
  ChaosGameParams params = SquareMeasure(uint64_t{1} << 22, 3);
  params.ifs.probabilities = {0.25, 0.25, 0.25, 0.25};
  params.frame.resolution = {8, 8, 1};
  const CountGrid counts = RunGame(params, 1);
  const double expected = double(params.iterations) / 64;
  for (int x = 0; x < 8; ++x)
    for (int y = 0; y < 8; ++y)
      EXPECT_NEAR(counts.Get(x, y, 0), expected, 6 * std::sqrt(expected * 3));
}

bool SameCounts(const CountGrid& a, const CountGrid& b) {
  const Int3 r = a.resolution();
  for (int x = 0; x < r.x; ++x)
    for (int y = 0; y < r.y; ++y)
      for (int z = 0; z < r.z; ++z)
        if (a.Get(x, y, z) != b.Get(x, y, z)) return false;
  return true;
}

TEST(ChaosGame, SameSeedSameCountsWhateverTheThreadCount) {
  ChaosGameParams params = SquareMeasure(5'000'000, 11);
  const CountGrid one = RunGame(params, 1);
  const CountGrid two = RunGame(params, 2);
  const CountGrid three = RunGame(params, 3);
  EXPECT_TRUE(SameCounts(one, two));
  EXPECT_TRUE(SameCounts(one, three));
  params.seed = 12;
  EXPECT_FALSE(SameCounts(one, RunGame(params, 2)));
}

TEST(ChaosGame, RoundsDoNotChangeTheResult) {
  ChaosGameParams params = SquareMeasure(5'000'000, 5);
  auto game = ChaosGame::Create(params, 2);
  ASSERT_TRUE(game.ok());
  for (uint64_t it = 1'000'000; !(*game)->done(); it += 1'300'000)
    ASSERT_TRUE((*game)->RunUntil(it, nullptr).ok());
  EXPECT_EQ((*game)->stats().iterations_done, params.iterations);
  EXPECT_TRUE(SameCounts((*game)->TakeCounts(), RunGame(params, 1)));
}

TEST(ChaosGame, CountsPointsOutsideTheBounds) {
  ChaosGameParams params = SquareMeasure(1'000'000, 1);
  params.frame.bounds = {{0, 0, -0.5}, {0.5, 0.5, 0.5}};  // only map 0's quarter
  auto game = ChaosGame::Create(params, 2);
  ASSERT_TRUE(game.ok());
  ASSERT_TRUE((*game)->Run(nullptr).ok());
  const ChaosGameStats s = (*game)->stats();
  EXPECT_NEAR(double(s.outside) / s.iterations_done, 0.70, 0.01);
  EXPECT_EQ((*game)->TakeCounts().Total(), s.iterations_done - s.outside);
}

class StopAfter : public Interrupter {
 public:
  bool WasInterrupted(uint64_t, uint64_t) override { return ++calls_ > 2; }
  std::atomic<int> calls_{0};
};

TEST(ChaosGame, InterrupterStopsTheRun) {
  StopAfter stop;
  auto game = ChaosGame::Create(SquareMeasure(uint64_t{1} << 30, 1), 2);
  ASSERT_TRUE(game.ok());
  EXPECT_TRUE(absl::IsCancelled((*game)->Run(&stop)));
  EXPECT_LT((*game)->stats().iterations_done, uint64_t{1} << 26);
}

TEST(ChaosGame, RejectsBadParams) {
  ChaosGameParams params = SquareMeasure(10, 1);
  params.ifs.probabilities = {1, 2};
  EXPECT_FALSE(ChaosGame::Create(params, 1).ok());
  params = SquareMeasure(10, 1);
  params.ifs.maps.clear();
  EXPECT_FALSE(ChaosGame::Create(params, 1).ok());
  params = SquareMeasure(10, 1);
  params.frame.resolution = {0, 4, 4};
  EXPECT_FALSE(ChaosGame::Create(params, 1).ok());
}

TEST(ChaosGame, NonFinitePointsAreReseededAndCounted) {
  ChaosGameParams params = SquareMeasure(100'000, 1);
  PointMap bad;
  bad.pre = Affine3::Scale({1e300, 1e300, 1e300});  // overflows to inf quickly
  bad.post = Affine3::Scale({1e300, 1e300, 1e300});
  params.ifs.maps.push_back(bad);
  params.ifs.probabilities = {0.3, 0.2, 0.2, 0.2, 0.1};
  auto game = ChaosGame::Create(params, 2);
  ASSERT_TRUE(game.ok());
  ASSERT_TRUE((*game)->Run(nullptr).ok());
  EXPECT_GT((*game)->stats().reseeded, 0u);
}

TEST(ChaosGame, MarkovChainRestrictsTransitions) {
  // Two states: state 0 only applies map 0 and moves to state 1, which only
  // applies map 3 and moves back. Plotted points then land in the cells
  // reached by words ending ...0 3 0 3.
  ChaosGameParams params = SquareMeasure(200'000, 1);
  MarkovChain chain;
  chain.states.resize(2);
  chain.states[0].transitions = {{0, 1}};
  chain.states[0].probabilities = {1};
  chain.states[1].transitions = {{3, 0}};
  chain.states[1].probabilities = {1};
  chain.states[1].plotted = false;
  params.chain = chain;
  const CountGrid counts = RunGame(params, 2);
  // Plotted after map 0 (in state 1? no: after moving to state 0 via map 3).
  uint64_t upper_right = 0;
  for (int x = 32; x < 64; ++x)
    for (int y = 32; y < 64; ++y) upper_right += counts.Get(x, y, 0);
  EXPECT_EQ(upper_right, counts.Total());
  EXPECT_NEAR(double(counts.Total()), 100'000, 1);
}

}  // namespace
}  // namespace nimbus
