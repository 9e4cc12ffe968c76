// The random IFS explorer (docs/explore.md): random IFS drawn from a seed,
// the contraction test checked against an independent oracle, thumbnails
// that do not depend on the thread count, and the contact sheet's layout.
#include <gtest/gtest.h>

#include <cmath>

#include "core/chaos/ifs_explorer.h"
#include "core/chaos/random_ifs.h"
#include "core/grid/contact_sheet.h"
#include "tests/support/contraction_oracle.h"
#include "tests/support/look_oracles.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

using testing::LinearBlock;
using testing::OracleAbsDeterminant;
using testing::OracleLargestSingularValue;

std::vector<double> Values(const Affine3& a) {
  std::vector<double> v;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 4; ++c) v.push_back(a.m[r][c]);
  return v;
}

// The oracle's contraction of an IFS, from its maps' raw numbers.
double OracleContraction(const std::vector<PointMap>& maps, int dims, ContractionMeasure m) {
  double out = 0;
  for (const PointMap& map : maps) {
    const auto block = LinearBlock(Values(map.pre), dims);
    if (m == ContractionMeasure::kDeterminant)
      out += OracleAbsDeterminant(block);
    else
      out = std::max(out, OracleLargestSingularValue(block));
  }
  return out;
}

// Small and quick: 48-pixel thumbnails of 2^16 points.
ExploreParams Small(int dims, int count) {
  ExploreParams p;
  p.draw.dimensions = dims;
  if (dims == 3) p.draw.coefficient_range = 0.6;
  p.seed = 11;
  p.count = count;
  p.thumbnail_size = 48;
  p.thumbnail_iterations = uint64_t{1} << 16;
  p.look.glow = 0.5;
  p.look.glow_radius = 1;
  return p;
}

struct Explored {
  std::vector<ExploreCandidate> kept;
  std::vector<RgbImage> thumbs;
  ExploreStats stats;
};

Explored Explore(const ExploreParams& p, int threads) {
  Explored run;
  auto stats = ExploreIfs(p, threads, nullptr, [&](const ExploreCandidate& c, RgbImage t) {
    run.kept.push_back(c);
    run.thumbs.push_back(std::move(t));
    return absl::OkStatus();
  });
  EXPECT_TRUE(stats.ok()) << stats.status();
  if (stats.ok()) run.stats = *stats;
  return run;
}

TEST(ContractionOracle, MatchesKnownMatrices) {
  // diag(3, 2) rotated: singular values 3 and 2, |det| 6.
  const double c = std::cos(0.3), s = std::sin(0.3);
  const testing::SquareMatrix a = {{3 * c, -2 * s}, {3 * s, 2 * c}};
  EXPECT_NEAR(OracleLargestSingularValue(a), 3, 1e-12);
  EXPECT_NEAR(OracleAbsDeterminant(a), 6, 1e-12);
  const testing::SquareMatrix b = {{1, 2, 0}, {0, 1, 0}, {0, 0, 0.5}};
  // [[1, 2], [0, 1]] has singular values 1 +- sqrt 2.
  EXPECT_NEAR(OracleLargestSingularValue(b), 1 + std::sqrt(2.0), 1e-12);
  EXPECT_NEAR(OracleAbsDeterminant(b), 0.5, 1e-12);
}

TEST(RandomIfs, IsAPureFunctionOfSeedAndAttemptWithinItsRanges) {
  RandomIfsParams p;
  p.min_maps = 2;
  p.max_maps = 6;
  p.coefficient_range = 0.7;
  p.translation_range = 2;
  std::vector<int> seen(7, 0);
  for (uint64_t attempt = 0; attempt < 500; ++attempt) {
    const auto maps = DrawRandomIfs(p, 5, attempt);
    const auto again = DrawRandomIfs(p, 5, attempt);
    ASSERT_EQ(maps.size(), again.size());
    for (size_t i = 0; i < maps.size(); ++i) EXPECT_EQ(maps[i].pre, again[i].pre);
    ASSERT_GE(maps.size(), 2u);
    ASSERT_LE(maps.size(), 6u);
    ++seen[maps.size()];
    for (const PointMap& m : maps) {
      for (int r = 0; r < 2; ++r) {
        for (int c = 0; c < 2; ++c) EXPECT_LE(std::fabs(m.pre.m[r][c]), 0.7);
        EXPECT_LE(std::fabs(m.pre.m[r][3]), 2);
      }
      // Planar: z is only halved, never mixed with x or y.
      EXPECT_EQ(m.pre.m[2][0], 0);
      EXPECT_EQ(m.pre.m[2][1], 0);
      EXPECT_EQ(m.pre.m[0][2], 0);
      EXPECT_EQ(m.pre.m[2][2], kPlanarZScale);
      EXPECT_TRUE(m.variations.empty());
    }
  }
  for (int n = 2; n <= 6; ++n) EXPECT_GT(seen[size_t(n)], 50) << n << " maps";
  EXPECT_NE(DrawRandomIfs(p, 5, 0)[0].pre, DrawRandomIfs(p, 6, 0)[0].pre);
}

TEST(RandomIfs, MeasuresAgreeWithTheOracle) {
  for (int dims : {2, 3}) {
    RandomIfsParams p;
    p.dimensions = dims;
    for (uint64_t attempt = 0; attempt < 200; ++attempt) {
      const auto maps = DrawRandomIfs(p, 1, attempt);
      for (ContractionMeasure m : {ContractionMeasure::kSingularValue,
                                   ContractionMeasure::kDeterminant})
        EXPECT_NEAR(IfsContraction(maps, dims, m), OracleContraction(maps, dims, m), 1e-9);
    }
  }
}

TEST(RandomIfs, VariationsAreDrawnFromTheList) {
  RandomIfsParams p;
  p.variations = {VariationKind::kSpherical, VariationKind::kSwirl};
  p.variation_probability = 0.5;
  int with = 0, total = 0;
  for (uint64_t attempt = 0; attempt < 200; ++attempt)
    for (const PointMap& m : DrawRandomIfs(p, 3, attempt)) {
      ++total;
      if (m.variations.empty()) continue;
      ++with;
      ASSERT_EQ(m.variations.size(), 1u);
      EXPECT_TRUE(m.variations[0].kind == VariationKind::kSpherical ||
                  m.variations[0].kind == VariationKind::kSwirl);
    }
  EXPECT_NEAR(double(with) / total, 0.5, 0.08);
  // The list does not change the affine parts.
  RandomIfsParams affine = p;
  affine.variations.clear();
  EXPECT_EQ(DrawRandomIfs(p, 3, 9)[0].pre, DrawRandomIfs(affine, 3, 9)[0].pre);
}

TEST(Explore, EveryKeptCandidateIsBelowTheThresholdByTheOracle) {
  for (int dims : {2, 3})
    for (ContractionMeasure m : {ContractionMeasure::kSingularValue,
                                 ContractionMeasure::kDeterminant}) {
      ExploreParams p = Small(dims, 4);
      p.measure = m;
      // Tight enough that some IFS fail (3D determinants of small entries
      // are small).
      p.threshold = m == ContractionMeasure::kDeterminant ? (dims == 3 ? 0.15 : 0.6) : 0.85;
      const Explored run = Explore(p, 2);
      ASSERT_EQ(run.kept.size(), 4u) << dims << "D";
      EXPECT_GT(run.stats.attempts, run.stats.contractive);
      for (const ExploreCandidate& c : run.kept) {
        const double oracle = OracleContraction(c.params.ifs.maps, dims, m);
        EXPECT_LT(oracle, p.threshold);
        EXPECT_NEAR(c.contraction, oracle, 1e-9);
        EXPECT_GE(c.coverage, p.min_coverage);
        // The kept IFS is the one the seed draws for that attempt.
        const auto maps = DrawRandomIfs(p.draw, p.seed, c.attempt);
        ASSERT_EQ(maps.size(), c.params.ifs.maps.size());
        for (size_t i = 0; i < maps.size(); ++i) EXPECT_EQ(maps[i].pre, c.params.ifs.maps[i].pre);
      }
    }
}

TEST(Explore, ThumbnailsAreTheSameOnOneAndTwoThreads) {
  for (int dims : {2, 3}) {
    const ExploreParams p = Small(dims, 3);
    const Explored one = Explore(p, 1), two = Explore(p, 2);
    ASSERT_EQ(one.kept.size(), two.kept.size());
    for (size_t i = 0; i < one.kept.size(); ++i) {
      EXPECT_EQ(one.kept[i].attempt, two.kept[i].attempt);
      EXPECT_EQ(one.kept[i].params.frame.bounds.min, two.kept[i].params.frame.bounds.min);
      EXPECT_EQ(one.kept[i].params.frame.bounds.max, two.kept[i].params.frame.bounds.max);
      EXPECT_EQ(one.thumbs[i].rgb, two.thumbs[i].rgb) << dims << "D thumbnail " << i;
    }
  }
}

TEST(Explore, StopsAtMaxAttemptsWithWhatItKept) {
  ExploreParams p = Small(2, 50);
  p.max_attempts = 300;
  const Explored run = Explore(p, 2);
  EXPECT_EQ(run.stats.attempts, 300u);
  EXPECT_LT(run.kept.size(), 50u);
  EXPECT_EQ(run.stats.kept, run.kept.size());
}

TEST(Explore, CancelsInsideARender) {
  ExploreParams p = Small(2, 8);
  p.thumbnail_iterations = uint64_t{1} << 24;
  testing::CancelAfter cancel(40);
  int kept = 0;
  auto stats = ExploreIfs(p, 2, &cancel, [&](const ExploreCandidate&, RgbImage) {
    ++kept;
    return absl::OkStatus();
  });
  EXPECT_TRUE(absl::IsCancelled(stats.status())) << stats.status();
  EXPECT_LT(kept, 8);
}

TEST(ContactSheet, LayoutIsSquareishWithGaps) {
  const SheetLayout l = ContactSheetLayout(10, 64, 0);
  EXPECT_EQ(l.columns, 4);
  EXPECT_EQ(l.rows, 3);
  EXPECT_EQ(l.gap, 2);
  EXPECT_EQ(l.width(), 4 * 64 + 5 * 2);
  EXPECT_EQ(l.height(), 3 * 64 + 4 * 2);
  EXPECT_EQ(ContactSheetLayout(64, 256, 0).columns, 8);
  EXPECT_EQ(ContactSheetLayout(64, 256, 0).gap, 8);
  EXPECT_EQ(ContactSheetLayout(3, 16, 10).columns, 3);
  EXPECT_EQ(ContactSheetLayout(7, 16, 2).rows, 4);
}

TEST(ContactSheet, CopiesEachThumbnailIntoItsCell) {
  const SheetLayout l = ContactSheetLayout(5, 16, 0);
  std::vector<RgbImage> thumbs(5);
  for (size_t i = 0; i < thumbs.size(); ++i) {
    thumbs[i].width = thumbs[i].height = 16;
    thumbs[i].rgb.assign(16 * 16 * 3, float(i + 1) / 10);
  }
  auto sheet = ComposeContactSheet(thumbs, l, {0.5, 0.25, 0}, false);
  ASSERT_TRUE(sheet.ok()) << sheet.status();
  ASSERT_EQ(sheet->width, l.width());
  ASSERT_EQ(sheet->height, l.height());
  for (int i = 0; i < 5; ++i)
    EXPECT_EQ(sheet->At(l.CellX(i) + 15, l.CellY(i) + 15)[0], float(i + 1) / 10);
  EXPECT_EQ(sheet->At(0, 0)[0], 0.5f);  // the border
  EXPECT_EQ(sheet->At(l.CellX(5), l.CellY(5))[1], 0.25f);  // the empty sixth cell
  // Labels: white digits on black in the top-left corner.
  auto labelled = ComposeContactSheet(thumbs, l, {0.5, 0.25, 0}, true);
  ASSERT_TRUE(labelled.ok());
  EXPECT_EQ(labelled->At(l.CellX(0), l.CellY(0))[0], 0.f);
  int white = 0;
  for (int y = 0; y < 7; ++y)
    for (int x = 0; x < 5; ++x) white += labelled->At(l.CellX(0) + x, l.CellY(0) + y)[0] == 1.f;
  EXPECT_EQ(white, 8);  // the "1" glyph's pixels
  thumbs[2].width = 8;
  EXPECT_FALSE(ComposeContactSheet(thumbs, l, {}, false).ok());
}

// Coverage is the fraction of thumbnail pixels any point reached, counted
// here from the developed thumbnail itself: with no glow and a background
// no lit pixel can have, a lit pixel is one that differs from it.
TEST(Explore, CoverageIsTheThumbnailsLitFraction) {
  ExploreParams p = Small(2, 4);
  p.look.glow = 0;
  p.look.background = {-1, -1, -1};
  p.min_coverage = 0.1;
  const Explored run = Explore(p, 2);
  ASSERT_EQ(run.kept.size(), 4u);
  for (size_t i = 0; i < run.kept.size(); ++i) {
    const double lit = testing::LitFraction(run.thumbs[i], p.look.background);
    EXPECT_GE(lit, p.min_coverage) << i;
    EXPECT_LT(lit, 1) << i;
    EXPECT_DOUBLE_EQ(run.kept[i].coverage, lit) << "candidate " << i;
  }
}

}  // namespace
}  // namespace nimbus
