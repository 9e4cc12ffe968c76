#include "core/matrix/ifs_matrix.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <set>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "tests/support/matrix_oracles.h"

namespace nimbus {
namespace {

using ::nimbus::testing::DeterministicRenderOptions;
using ::nimbus::testing::IfsMatrixExample;
using ::nimbus::testing::RenderComponentDeterministic;
using ::nimbus::testing::RunChainReference;
using ::nimbus::testing::TreeMatrixExample;
using ::testing::HasSubstr;
using Entry = IfsMatrix::Entry;
using Voxel = std::array<int, 3>;
using VoxelSet = std::set<Voxel>;

// The tree lives in the x = 0 plane; y in [0, ~2], z in [-1, 1].
GridFrame TreeFrame() {
  GridFrame f;
  f.resolution = {1, 96, 96};
  f.bounds = {{-0.5, -0.5, -1.5}, {0.5, 2.5, 1.5}};
  return f;
}

// Voxels of points; every point must be inside the frame.
VoxelSet VoxelsOf(const std::vector<Vec3>& pts, const GridFrame& f) {
  VoxelSet out;
  const Vec3 h = f.VoxelSize();
  for (const Vec3& p : pts) {
    const Voxel v{int(std::floor((p.x - f.bounds.min.x) / h.x)),
                  int(std::floor((p.y - f.bounds.min.y) / h.y)),
                  int(std::floor((p.z - f.bounds.min.z) / h.z))};
    EXPECT_TRUE(v[0] >= 0 && v[0] < f.resolution.x && v[1] >= 0 && v[1] < f.resolution.y &&
                v[2] >= 0 && v[2] < f.resolution.z)
        << "point (" << p.x << ", " << p.y << ", " << p.z << ") is outside the frame";
    out.insert(v);
  }
  return out;
}

VoxelSet VoxelsOf(const CountGrid& g) {
  VoxelSet out;
  const Int3 res = g.resolution();
  g.ForEachVoxel([&](Int3 c, uint32_t) {
    const Voxel v{c.x, c.y, c.z};
    if (v[0] < res.x && v[1] < res.y && v[2] < res.z) out.insert(v);
  });
  return out;
}

// Voxels of `sub` with no voxel of `big` within Chebyshev distance r.
std::vector<Voxel> Missing(const VoxelSet& sub, const VoxelSet& big, int r) {
  std::vector<Voxel> out;
  for (const Voxel& v : sub) {
    bool found = false;
    for (int dx = -r; dx <= r && !found; ++dx)
      for (int dy = -r; dy <= r && !found; ++dy)
        for (int dz = -r; dz <= r && !found; ++dz)
          found = big.count({v[0] + dx, v[1] + dy, v[2] + dz}) > 0;
    if (!found) out.push_back(v);
  }
  return out;
}

std::vector<Vec3> Render(const std::vector<PointMap>& maps, const IfsMatrix& m, Component c,
                         int depth) {
  auto pts = RenderComponentDeterministic(maps, m, c, depth);
  EXPECT_TRUE(pts.ok()) << pts.status();
  return pts.ok() ? *pts : std::vector<Vec3>{};
}

// Per-label grids of a reference chaos game over the chain for `selection`.
std::vector<VoxelSet> ChaosVoxels(const std::vector<PointMap>& maps, const IfsMatrix& m,
                                  const std::vector<Component>& selection, const GridFrame& f,
                                  uint64_t iterations, uint64_t seed = 1) {
  auto chain = BuildComponentChain(maps, m, selection, "test");
  EXPECT_TRUE(chain.ok()) << chain.status();
  if (!chain.ok()) return {};
  auto run = RunChainReference(maps, chain->chain, f, iterations, 50, seed);
  EXPECT_TRUE(run.ok()) << run.status();
  if (!run.ok()) return {};
  EXPECT_EQ(run->outside, 0u);
  std::vector<VoxelSet> out;
  for (const CountGrid& g : run->labels) out.push_back(VoxelsOf(g));
  return out;
}

PointMap Affine(std::string name, Affine3 a) {
  PointMap m;
  m.name = std::move(name);
  m.pre = a;
  return m;
}

Affine3 Half() { return Affine3::Scale({0.5, 0.5, 0.5}); }

// Distance from p to the segment a-b.
double SegmentDistance(Vec3 p, Vec3 a, Vec3 b) {
  const Vec3 d = b - a;
  const double t = std::clamp(Dot(p - a, d) / Dot(d, d), 0.0, 1.0);
  return Length(p - (a + t * d));
}

// Sets of base-map words in an entry.
std::set<std::vector<uint32_t>> Words(const MapTable& table, const Entry& e) {
  std::set<std::vector<uint32_t>> out;
  for (uint32_t f : e) out.insert(table.word(f));
  return out;
}

// ---------------------------------------------------------------------------
// The tree of docs/algorithms.md#worked-example-the-tree.

TEST(TreeExample, TrunkComponentIsTheSegment) {
  const IfsMatrixExample tree = TreeMatrixExample();
  // Deterministic: {T1, T2}^10 (origin) are the 1024 dyadic points of the trunk.
  const std::vector<Vec3> pts = Render(tree.maps, tree.matrix, {1, 1}, 10);
  ASSERT_EQ(pts.size(), 1024u);
  std::set<long> ys;
  for (const Vec3& p : pts) {
    EXPECT_NEAR(p.x, 0, 1e-12);
    EXPECT_NEAR(p.z, 0, 1e-12);
    EXPECT_GE(p.y, -1e-12);
    EXPECT_LE(p.y, 1 + 1e-12);
    ys.insert(std::lround(p.y * 1024));
  }
  EXPECT_EQ(ys.size(), 1024u);

  // Chaos game: every plotted voxel touches the segment, and the segment's
  // voxels are all hit.
  const GridFrame f = TreeFrame();
  const auto grids = ChaosVoxels(tree.maps, tree.matrix, {{1, 1}}, f, 200000);
  ASSERT_EQ(grids.size(), 1u);
  const Vec3 h = f.VoxelSize();
  const double tolerance = Length(h);  // voxel centre to segment, one voxel
  for (const Voxel& v : grids[0])
    EXPECT_LE(SegmentDistance(f.VoxelCenter({v[0], v[1], v[2]}), {0, 0, 0}, {0, 1, 0}), tolerance)
        << v[1] << "," << v[2];
  const VoxelSet segment = VoxelsOf(pts, f);
  EXPECT_TRUE(Missing(segment, grids[0], 0).empty());
}

TEST(TreeExample, CanopyComponentIsTheAttractorOfT3T4) {
  const IfsMatrixExample tree = TreeMatrixExample();
  // (H^k)_00 is {T3, T4}^k: the words of the canopy's IFS alone.
  const std::vector<Vec3> pts = Render(tree.maps, tree.matrix, {0, 0}, 8);
  EXPECT_EQ(pts.size(), 256u);
  auto canopy = IfsMatrix::FromRows({{{2, 3}}});
  ASSERT_TRUE(canopy.ok());
  const std::vector<Vec3> direct = Render(tree.maps, *canopy, {0, 0}, 8);
  EXPECT_EQ(std::set<Voxel>(VoxelsOf(pts, TreeFrame())), VoxelsOf(direct, TreeFrame()));
  // Rows and columns that cannot be reached stay empty.
  EXPECT_TRUE(Render(tree.maps, tree.matrix, {1, 0}, 8).empty());
}

TEST(TreeExample, BranchComponentContainsTrunk) {
  const IfsMatrixExample tree = TreeMatrixExample();
  // Word level: the words of (1,1) are the words of (0,1) with no T3/T4.
  const std::vector<Vec3> trunk = Render(tree.maps, tree.matrix, {1, 1}, 9);
  const std::vector<Vec3> branch = Render(tree.maps, tree.matrix, {0, 1}, 9);
  EXPECT_EQ(branch.size(), 9u * 512u);  // sum over a + b = 9, b >= 1 of 2^a 2^b
  const GridFrame f = TreeFrame();
  EXPECT_TRUE(Missing(VoxelsOf(trunk, f), VoxelsOf(branch, f), 0).empty());

  // Voxel level, one combined chain: label 0 is A_12, label 1 is A_22.
  const auto grids = ChaosVoxels(tree.maps, tree.matrix, {{0, 1}, {1, 1}}, f, 400000);
  ASSERT_EQ(grids.size(), 2u);
  EXPECT_GT(grids[0].size(), 3 * grids[1].size());  // the branches add a lot
  const auto missing = Missing(grids[1], grids[0], 0);
  EXPECT_TRUE(missing.empty()) << missing.size() << " trunk voxels not in the tree";
}

TEST(TreeExample, ComponentsLieInTheUnionAttractor) {
  const IfsMatrixExample tree = TreeMatrixExample();
  const GridFrame f = TreeFrame();
  // The union IFS {T1..T4} as a one-state matrix. Its depth-9 render is
  // within 0.5^9 * diam of the attractor: well under a voxel.
  auto all = IfsMatrix::FromRows({{{0, 1, 2, 3}}});
  ASSERT_TRUE(all.ok());
  const VoxelSet union_voxels = VoxelsOf(Render(tree.maps, *all, {0, 0}, 9), f);

  const std::vector<Component> comps = {{0, 0}, {0, 1}, {1, 1}};
  for (const Component& c : comps) {
    // Exact: every word of a component is a word of the union.
    EXPECT_TRUE(
        Missing(VoxelsOf(Render(tree.maps, tree.matrix, c, 9), f), union_voxels, 0).empty());
  }
  // Chaos game over all three components at once: two column blocks, so a
  // hub state shares the restarts between the canopy's and the trunk's
  // warm-ups, and the walk starts there.
  auto chain = BuildComponentChain(tree.maps, tree.matrix, comps, "tree");
  ASSERT_TRUE(chain.ok()) << chain.status();
  int hubs = 0;
  for (const auto& info : chain->states) hubs += info.kind == ComponentChain::Kind::kRestart;
  EXPECT_EQ(hubs, 1);
  EXPECT_EQ(chain->states[chain->chain.start_state].kind, ComponentChain::Kind::kRestart);
  EXPECT_EQ(chain->chain.states[chain->chain.start_state].transitions.size(), 2u);
  const auto grids = ChaosVoxels(tree.maps, tree.matrix, comps, f, 600000);
  ASSERT_EQ(grids.size(), 3u);
  for (size_t k = 0; k < comps.size(); ++k) {
    EXPECT_FALSE(grids[k].empty()) << "component " << k;
    const auto missing = Missing(grids[k], union_voxels, 1);
    EXPECT_TRUE(missing.empty()) << "component " << k << ": " << missing.size()
                                 << " voxels outside the union attractor";
  }
}

TEST(TreeExample, ChaosGameCoversTheDeterministicBranches) {
  const IfsMatrixExample tree = TreeMatrixExample();
  const GridFrame f = TreeFrame();
  // The restarts must keep the trunk-side states alive: the chaos game of
  // A_12 and its deterministic render agree both ways up to one voxel.
  const VoxelSet det = VoxelsOf(Render(tree.maps, tree.matrix, {0, 1}, 11), f);
  const auto grids = ChaosVoxels(tree.maps, tree.matrix, {{0, 1}}, f, 1000000, 5);
  ASSERT_EQ(grids.size(), 1u);
  EXPECT_TRUE(Missing(grids[0], det, 1).empty());
  EXPECT_TRUE(Missing(det, grids[0], 1).empty()) << Missing(det, grids[0], 1).size();
}

TEST(TreeExample, ChainStructure) {
  const IfsMatrixExample tree = TreeMatrixExample();
  // Only the trunk: row 0 cannot be reached from row 1, so it is pruned.
  auto trunk = BuildComponentChain(tree.maps, tree.matrix, {{1, 1}}, "tree");
  ASSERT_TRUE(trunk.ok()) << trunk.status();
  int live = 0;
  for (size_t s = 0; s < trunk->states.size(); ++s) {
    const auto& info = trunk->states[s];
    const ChainState& st = trunk->chain.states[s];
    EXPECT_EQ(info.row, 1u);
    EXPECT_EQ(info.col, 1u);
    if (info.kind == ComponentChain::Kind::kLive) {
      ++live;
      EXPECT_TRUE(st.plotted);
      EXPECT_EQ(st.label, 0);
      // A sink class in a single block never restarts: T1, T2 only.
      EXPECT_EQ(st.transitions.size(), 2u);
    } else {
      EXPECT_FALSE(st.plotted);
    }
  }
  EXPECT_EQ(live, 1);
  const auto& start = trunk->states[trunk->chain.start_state];
  EXPECT_EQ(start.kind, ComponentChain::Kind::kWarmup);
  EXPECT_EQ(start.level, 0u);
  // log(1e-5) / log(0.5) = 16.6: 17 warm-up copies of the trunk state.
  EXPECT_EQ(trunk->states.size(), 18u);

  // A_12: both rows live, only row 0 plotted; row 0 restarts.
  auto branch = BuildComponentChain(tree.maps, tree.matrix, {{0, 1}}, "tree");
  ASSERT_TRUE(branch.ok()) << branch.status();
  for (size_t s = 0; s < branch->states.size(); ++s) {
    const auto& info = branch->states[s];
    const ChainState& st = branch->chain.states[s];
    double total = 0;
    for (double p : st.probabilities) total += p;
    EXPECT_NEAR(total, 1.0, 1e-12);
    if (info.kind != ComponentChain::Kind::kLive) continue;
    EXPECT_EQ(st.plotted, info.row == 0);
    if (info.row == 0) {
      // T3, T4 back to row 0, plus one restart into the trunk's warm-up.
      ASSERT_EQ(st.transitions.size(), 3u);
      const auto& next = branch->states[st.transitions[2].next_state];
      EXPECT_EQ(next.kind, ComponentChain::Kind::kWarmup);
      EXPECT_EQ(next.level, 0u);
    } else {
      // From the trunk: T1, T2 stay, T1, T2 move to row 0 (f(A_22) in A_12).
      EXPECT_EQ(st.transitions.size(), 4u);
    }
  }
}

// ---------------------------------------------------------------------------
// Checks

IfsMatrix Pattern(const std::vector<std::vector<int>>& rows) {
  IfsMatrix m(uint32_t(rows.size()));
  for (uint32_t i = 0; i < rows.size(); ++i)
    for (uint32_t j = 0; j < rows.size(); ++j)
      if (rows[i][j]) m.Insert(i, j, 0);
  return m;
}

TEST(Aperiodicity, PeriodicPatternIsRejected) {
  const IfsMatrix swap = Pattern({{0, 1}, {1, 0}});
  const absl::Status s = CheckAperiodic(swap, "swap");
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(std::string(s.message()), HasSubstr("'swap'"));
  EXPECT_THAT(std::string(s.message()), HasSubstr("period 2"));
  EXPECT_EQ(AnalyzePowers(BoolMatrix::PatternOf(Pattern({{0, 1, 0}, {0, 0, 1}, {1, 0, 0}}))).period,
            3u);
  // The chain builder refuses it too.
  std::vector<PointMap> maps = {Affine("f", Half())};
  EXPECT_EQ(BuildComponentChain(maps, swap, {{0, 0}}, "swap").status().code(),
            absl::StatusCode::kInvalidArgument);
}

TEST(Aperiodicity, AperiodicPatternsAreAccepted) {
  const IfsMatrixExample tree = TreeMatrixExample();
  EXPECT_TRUE(CheckAperiodic(tree.matrix, "tree").ok());
  const PowerAnalysis a = AnalyzePowers(BoolMatrix::PatternOf(tree.matrix));
  EXPECT_EQ(a.index, 1u);
  // A 2-cycle plus a 3-cycle through state 0 is primitive: gcd(2, 3) = 1.
  const IfsMatrix primitive = Pattern({{0, 1, 1, 0}, {1, 0, 0, 0}, {0, 0, 0, 1}, {1, 0, 0, 0}});
  const PowerAnalysis p = AnalyzePowers(BoolMatrix::PatternOf(primitive));
  EXPECT_TRUE(p.aperiodic());
  EXPECT_GT(p.index, 1u);
  for (uint32_t i = 0; i < 4; ++i)
    for (uint32_t j = 0; j < 4; ++j) EXPECT_TRUE(p.limit.Get(i, j));
  // Nilpotent: aperiodic, every component empty in the limit.
  const IfsMatrix nil = Pattern({{0, 1}, {0, 0}});
  auto limit = AperiodicLimitPattern(nil, "nil");
  ASSERT_TRUE(limit.ok());
  const absl::Status s = CheckSelection(*limit, {{0, 1}}, "nil");
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(std::string(s.message()), HasSubstr("component (0, 1)"));
  EXPECT_THAT(std::string(s.message()), HasSubstr("'nil'"));
}

// Brute force: powers until a repeat, compared with the squaring analysis.
TEST(Aperiodicity, AgreesWithNaivePowers) {
  Rng rng(42, 0);
  for (int trial = 0; trial < 300; ++trial) {
    const uint32_t n = 1 + uint32_t(rng.Uniform() * 7);
    const double density = rng.Uniform(0.1, 0.5);
    BoolMatrix r(n);
    for (uint32_t i = 0; i < n; ++i)
      for (uint32_t j = 0; j < n; ++j)
        if (rng.Uniform() < density) r.Set(i, j);
    std::vector<BoolMatrix> seen{r};
    uint64_t first = 0, period = 0;
    while (period == 0) {
      const BoolMatrix next = seen.back() * r;
      for (size_t k = 0; k < seen.size(); ++k)
        if (seen[k] == next) first = k + 1, period = seen.size() - k;
      seen.push_back(next);
    }
    const PowerAnalysis a = AnalyzePowers(r);
    EXPECT_EQ(a.period, period) << "trial " << trial;
    if (period == 1) {
      EXPECT_EQ(a.index, first) << "trial " << trial;
      EXPECT_EQ(a.limit, seen[first - 1]);
    }
  }
}

TEST(Selection, EmptyAndOutOfRangeComponentsAreRefused) {
  const IfsMatrixExample tree = TreeMatrixExample();
  auto chain = BuildComponentChain(tree.maps, tree.matrix, {{1, 0}}, "tree");
  EXPECT_EQ(chain.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(std::string(chain.status().message()),
              HasSubstr("component (1, 0) of IFS matrix 'tree'"));
  chain = BuildComponentChain(tree.maps, tree.matrix, {{0, 5}}, "tree");
  EXPECT_THAT(std::string(chain.status().message()), HasSubstr("outside"));
  chain = BuildComponentChain(tree.maps, tree.matrix, {}, "tree");
  EXPECT_EQ(chain.status().code(), absl::StatusCode::kInvalidArgument);
  IfsMatrix bad = tree.matrix;
  bad.Insert(0, 0, 9);
  EXPECT_THAT(std::string(BuildComponentChain(tree.maps, bad, {{0, 0}}, "tree").status().message()),
              HasSubstr("refers to map 9"));
}

TEST(Lookup, UnknownNamesGiveClearErrors) {
  MapTable table(TreeMatrixExample().maps);
  ASSERT_TRUE(table.Find("T3").ok());
  EXPECT_EQ(*table.Find("T3"), 2u);
  const absl::Status s = table.Find("T9").status();
  EXPECT_EQ(s.code(), absl::StatusCode::kNotFound);
  EXPECT_THAT(std::string(s.message()), HasSubstr("unknown map 'T9'"));
  EXPECT_THAT(std::string(s.message()), HasSubstr("T1, T2, T3, T4"));

  MatrixCatalog catalog;
  ASSERT_TRUE(catalog.Add("tree", TreeMatrixExample().matrix).ok());
  EXPECT_EQ(catalog.Add("tree", IfsMatrix(1)).code(), absl::StatusCode::kAlreadyExists);
  auto found = catalog.Find("tree");
  ASSERT_TRUE(found.ok());
  EXPECT_EQ((*found)->matrix, TreeMatrixExample().matrix);
  const absl::Status m = catalog.Find("forest").status();
  EXPECT_EQ(m.code(), absl::StatusCode::kNotFound);
  EXPECT_THAT(std::string(m.message()),
              HasSubstr("unknown IFS matrix 'forest'; defined matrices: tree"));
}

// ---------------------------------------------------------------------------
// Operations

// Six distinct affine maps m0..m5.
std::vector<PointMap> SixMaps() {
  std::vector<PointMap> maps;
  for (int i = 0; i < 6; ++i)
    maps.push_back(
        Affine(absl::StrCat("m", i), Affine3::Translate({0.1 * i, 0.2 * (i % 2), -0.05 * i}) *
                                         Affine3::Rotate({1, 1, double(i)}, 10.0 * i) *
                                         Affine3::Scale({0.5, 0.4 + 0.02 * i, 0.45})));
  return maps;
}

IfsMatrix RandomMatrix(Rng& rng, uint32_t n, uint32_t maps) {
  IfsMatrix m(n);
  for (uint32_t i = 0; i < n; ++i)
    for (uint32_t j = 0; j < n; ++j)
      for (uint32_t f = 0; f < maps; ++f)
        if (rng.Uniform() < 0.3) m.Insert(i, j, f);
  return m;
}

IfsMatrix Eval(const MatrixExprPtr& e, MapTable& table) {
  auto r = EvaluateMatrixExpr(*e, table);
  EXPECT_TRUE(r.ok()) << r.status();
  return r.ok() ? *r : IfsMatrix();
}

TEST(Operations, UnionIsCommutativeAndAssociative) {
  MapTable table(SixMaps());
  Rng rng(3, 0);
  for (int trial = 0; trial < 20; ++trial) {
    auto a = MatrixLeaf("a", RandomMatrix(rng, 3, 6));
    auto b = MatrixLeaf("b", RandomMatrix(rng, 3, 6));
    auto c = MatrixLeaf("c", RandomMatrix(rng, 3, 6));
    const IfsMatrix ab = Eval(MatrixUnion({a, b}), table);
    EXPECT_EQ(ab, Eval(MatrixUnion({b, a}), table));
    EXPECT_EQ(Eval(MatrixUnion({MatrixUnion({a, b}), c}), table),
              Eval(MatrixUnion({a, MatrixUnion({b, c})}), table));
    EXPECT_EQ(Eval(MatrixUnion({a, b, c}), table), Eval(MatrixUnion({c, a, b}), table));
    // Entrywise definition, and intersection alongside.
    const IfsMatrix i = Eval(MatrixIntersection({a, b}), table);
    for (uint32_t r = 0; r < 3; ++r)
      for (uint32_t s = 0; s < 3; ++s) {
        std::set<uint32_t> u(a->matrix.at(r, s).begin(), a->matrix.at(r, s).end());
        u.insert(b->matrix.at(r, s).begin(), b->matrix.at(r, s).end());
        EXPECT_EQ(std::set<uint32_t>(ab.at(r, s).begin(), ab.at(r, s).end()), u);
        for (uint32_t f : i.at(r, s)) {
          EXPECT_TRUE(std::count(a->matrix.at(r, s).begin(), a->matrix.at(r, s).end(), f));
          EXPECT_TRUE(std::count(b->matrix.at(r, s).begin(), b->matrix.at(r, s).end(), f));
        }
      }
    EXPECT_EQ(Eval(MatrixIntersection({a, b}), table), Eval(MatrixIntersection({b, a}), table));
  }
  EXPECT_EQ(table.size(), 6u);  // no operation above creates maps
}

TEST(Operations, CompositionFollowsItsDefinition) {
  MapTable table(SixMaps());
  // H = [[{0}, {1}], [{}, {2}]], K = [[{3}, {}], [{0}, {1, 2}]].
  auto h = MatrixLeaf("H", *IfsMatrix::FromRows({{{0}, {1}}, {{}, {2}}}));
  auto k = MatrixLeaf("K", *IfsMatrix::FromRows({{{3}, {}}, {{0}, {1, 2}}}));
  const IfsMatrix hk = Eval(MatrixComposition({h, k}), table);
  using W = std::set<std::vector<uint32_t>>;
  EXPECT_EQ(Words(table, hk.at(0, 0)), (W{{0, 3}, {1, 0}}));
  EXPECT_EQ(Words(table, hk.at(0, 1)), (W{{1, 1}, {1, 2}}));
  EXPECT_EQ(Words(table, hk.at(1, 0)), (W{{2, 0}}));
  EXPECT_EQ(Words(table, hk.at(1, 1)), (W{{2, 1}, {2, 2}}));

  // A composed map is f after g, numerically.
  const uint32_t fg = hk.at(0, 0)[0];
  const std::vector<uint32_t>& w = table.word(fg);
  const Vec3 p{0.3, -0.2, 0.7};
  Rng rng(0, 0);
  const Vec3 want = table.map(w[0]).Apply(table.map(w[1]).Apply(p, rng), rng);
  const Vec3 got = table.map(fg).Apply(p, rng);
  EXPECT_NEAR(Length(want - got), 0, 1e-12);
  EXPECT_TRUE(table.map(fg).IsAffine());
  EXPECT_EQ(table.map(fg).name, table.map(w[0]).name + "." + table.map(w[1]).name);

  // Associative by construction: composed maps are shared by word.
  auto l = MatrixLeaf("L", *IfsMatrix::FromRows({{{4}, {5}}, {{5}, {}}}));
  EXPECT_EQ(Eval(MatrixComposition({MatrixComposition({h, k}), l}), table),
            Eval(MatrixComposition({h, MatrixComposition({k, l})}), table));
  EXPECT_EQ(Eval(MatrixComposition({h, k, l}), table),
            Eval(MatrixComposition({h, MatrixComposition({k, l})}), table));
  const size_t size = table.size();
  Eval(MatrixComposition({h, k}), table);
  EXPECT_EQ(table.size(), size);
}

TEST(Operations, CompositionWithNonlinearMaps) {
  std::vector<PointMap> maps = SixMaps();
  PointMap wavy = Affine("wavy", Half());
  wavy.variations.push_back({VariationKind::kSinusoidal, 1.0, {}});
  maps.push_back(wavy);  // index 6
  MapTable table(maps);
  auto nl = MatrixLeaf("N", *IfsMatrix::FromRows({{{6}}}));
  auto af = MatrixLeaf("A", *IfsMatrix::FromRows({{{0}}}));
  // Affine after nonlinear folds into the post affine: exact.
  const IfsMatrix an = Eval(MatrixComposition({af, nl}), table);
  const uint32_t idx = an.at(0, 0)[0];
  ASSERT_TRUE(table.map(idx).post.has_value());
  Rng rng(0, 0);
  const Vec3 p{0.2, 0.4, -0.3};
  EXPECT_NEAR(
      Length(table.map(idx).Apply(p, rng) - table.map(0).Apply(table.map(6).Apply(p, rng), rng)), 0,
      1e-12);
  // Nonlinear after anything is refused, naming the map and the expression.
  auto bad = EvaluateMatrixExpr(*MatrixComposition({nl, af}), table);
  EXPECT_EQ(bad.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(std::string(bad.status().message()), HasSubstr("'wavy'"));
  EXPECT_THAT(std::string(bad.status().message()), HasSubstr("compose(N, A)"));
}

TEST(Operations, TensorProductDefinition) {
  MapTable table(SixMaps());
  Rng rng(9, 0);
  auto a = MatrixLeaf("a", RandomMatrix(rng, 2, 3));
  auto b = MatrixLeaf("b", RandomMatrix(rng, 3, 6));
  const IfsMatrix t = Eval(MatrixTensorProduct(a, b), table);
  ASSERT_EQ(t.size(), 6u);
  for (uint32_t i = 0; i < 2; ++i)
    for (uint32_t j = 0; j < 2; ++j)
      for (uint32_t k = 0; k < 3; ++k)
        for (uint32_t l = 0; l < 3; ++l) {
          std::set<uint32_t> u(a->matrix.at(i, j).begin(), a->matrix.at(i, j).end());
          u.insert(b->matrix.at(k, l).begin(), b->matrix.at(k, l).end());
          const Entry& e = t.at(i * 3 + k, j * 3 + l);
          EXPECT_EQ(std::set<uint32_t>(e.begin(), e.end()), u);
        }
}

// Three half-size maps in the tree's plane (x = 0), shifted towards +z.
std::vector<PointMap> TreePlusSegmentMaps() {
  std::vector<PointMap> maps = TreeMatrixExample().maps;
  maps.push_back(Affine("S1", Affine3::Translate({0, 0, 0.5}) * Half()));      // 4
  maps.push_back(Affine("S2", Affine3::Translate({0, 0.25, 0.75}) * Half()));  // 5
  maps.push_back(Affine("S3", Affine3::Translate({0, 0.5, 0.25}) * Half()));   // 6
  return maps;
}

TEST(Operations, TensorSumIsTheShuffle) {
  MapTable table(TreePlusSegmentMaps());
  const IfsMatrix tree = TreeMatrixExample().matrix;
  const IfsMatrix other = *IfsMatrix::FromRows({{{4}, {5}}, {{}, {5, 6}}});
  const IfsMatrix sum =
      Eval(MatrixTensorSum(MatrixLeaf("tree", tree), MatrixLeaf("other", other)), table);
  ASSERT_EQ(sum.size(), 4u);
  for (uint32_t i = 0; i < 2; ++i)
    for (uint32_t j = 0; j < 2; ++j)
      for (uint32_t k = 0; k < 2; ++k)
        for (uint32_t l = 0; l < 2; ++l) {
          std::set<uint32_t> want;
          if (k == l) want.insert(tree.at(i, j).begin(), tree.at(i, j).end());
          if (i == j) want.insert(other.at(k, l).begin(), other.at(k, l).end());
          const Entry& e = sum.at(i * 2 + k, j * 2 + l);
          EXPECT_EQ(std::set<uint32_t>(e.begin(), e.end()), want);
        }
  // Identity entries of I compose away: no identity map was needed.
  EXPECT_FALSE(table.Find("identity").ok());
  EXPECT_TRUE(CheckAperiodic(sum, "sum").ok());
}

TEST(Operations, TensorSumContainsBothOperands) {
  MapTable table(TreePlusSegmentMaps());
  const IfsMatrix tree = TreeMatrixExample().matrix;
  const IfsMatrix other = *IfsMatrix::FromRows({{{4}, {5}}, {{}, {5, 6}}});
  const IfsMatrix sum =
      Eval(MatrixTensorSum(MatrixLeaf("tree", tree), MatrixLeaf("other", other)), table);
  const std::vector<PointMap>& maps = table.maps();
  GridFrame f = TreeFrame();

  // Inclusion: A(H)_ij lies in A(sum)_{(i,l),(j,l)} for every l, and A(H')_kl
  // in A(sum)_{(i,k),(i,l)} for every i. Ground truth for the operands is
  // their deterministic render; the sum is sampled by the chaos game.
  std::vector<Component> wanted;
  std::vector<VoxelSet> operand;
  for (uint32_t i = 0; i < 2; ++i)
    for (uint32_t j = 0; j < 2; ++j) {
      if (i == 1 && j == 0) continue;  // empty in both operands
      const VoxelSet t = VoxelsOf(Render(maps, tree, {i, j}, 9), f);
      const VoxelSet o = VoxelsOf(Render(maps, other, {i, j}, 9), f);
      for (uint32_t l = 0; l < 2; ++l) {
        wanted.push_back({i * 2 + l, j * 2 + l});
        operand.push_back(t);
        wanted.push_back({l * 2 + i, l * 2 + j});
        operand.push_back(o);
      }
    }
  const auto grids = ChaosVoxels(maps, sum, wanted, f, 3000000, 11);
  for (size_t k = 0; k < wanted.size(); ++k) {
    // A repeated component is plotted under the label of its first mention.
    size_t label = 0;
    while (!(wanted[label] == wanted[k])) ++label;
    ASSERT_LT(label, grids.size());
    const auto missing = Missing(operand[k], grids[label], 1);
    EXPECT_TRUE(missing.empty()) << "sum component (" << wanted[k].row << ", " << wanted[k].col
                                 << ") misses " << missing.size() << " of " << operand[k].size()
                                 << " operand voxels";
  }
  // Word level (exact): the operand's words are words of the sum.
  for (uint32_t l = 0; l < 2; ++l) {
    const VoxelSet s = VoxelsOf(Render(maps, sum, {0 * 2 + l, 1 * 2 + l}, 6), f);
    EXPECT_TRUE(Missing(VoxelsOf(Render(maps, tree, {0, 1}, 6), f), s, 0).empty());
  }
}

TEST(Operations, BlockDiagonalKeepsComponents) {
  MapTable table(TreePlusSegmentMaps());
  const IfsMatrix tree = TreeMatrixExample().matrix;
  const IfsMatrix other = *IfsMatrix::FromRows({{{4}, {5}}, {{}, {5, 6}}});
  const IfsMatrix diag =
      Eval(MatrixBlockDiagonal({MatrixLeaf("tree", tree), MatrixLeaf("other", other)}), table);
  ASSERT_EQ(diag.size(), 4u);
  const std::vector<PointMap>& maps = table.maps();
  auto limit = AperiodicLimitPattern(diag, "diag");
  ASSERT_TRUE(limit.ok());
  for (uint32_t i = 0; i < 2; ++i)
    for (uint32_t j = 0; j < 2; ++j) {
      // Same words, hence the very same points.
      EXPECT_EQ(Render(maps, diag, {i, j}, 8).size(), Render(maps, tree, {i, j}, 8).size());
      const auto a = Render(maps, diag, {i, j}, 8), b = Render(maps, tree, {i, j}, 8);
      for (size_t p = 0; p < a.size() && p < b.size(); ++p) EXPECT_EQ(a[p], b[p]);
      const auto c = Render(maps, diag, {2 + i, 2 + j}, 8), d = Render(maps, other, {i, j}, 8);
      ASSERT_EQ(c.size(), d.size());
      for (size_t p = 0; p < c.size(); ++p) EXPECT_EQ(c[p], d[p]);
      // The off-diagonal blocks are empty in the limit.
      EXPECT_FALSE(limit->Get(i, 2 + j));
      EXPECT_FALSE(limit->Get(2 + i, j));
    }
  // The chain of a diagonal component is the operand's own chain, so the
  // same seed gives the same counts.
  auto c1 = BuildComponentChain(maps, diag, {{0, 1}}, "diag");
  auto c2 = BuildComponentChain(maps, tree, {{0, 1}}, "tree");
  ASSERT_TRUE(c1.ok() && c2.ok());
  ASSERT_EQ(c1->chain.states.size(), c2->chain.states.size());
  const GridFrame f = TreeFrame();
  auto r1 = RunChainReference(maps, c1->chain, f, 100000, 20, 4);
  auto r2 = RunChainReference(maps, c2->chain, f, 100000, 20, 4);
  ASSERT_TRUE(r1.ok() && r2.ok());
  EXPECT_EQ(VoxelsOf(r1->counts), VoxelsOf(r2->counts));
  EXPECT_EQ(r1->counts.Total(), r2->counts.Total());
}

TEST(Operations, ConcatenationRebuildsTheTree) {
  // {T3, T4} then, through an identity link, {T1, T2}: the same branching
  // tree as the example's A_12 (T1(trunk) u T2(trunk) is the trunk).
  MapTable table(TreeMatrixExample().maps);
  auto crown = MatrixLeaf("crown", *IfsMatrix::FromRows({{{2, 3}}}));
  auto trunk = MatrixLeaf("trunk", *IfsMatrix::FromRows({{{0, 1}}}));
  const IfsMatrix cat = Eval(MatrixConcatenation(crown, trunk), table);
  ASSERT_EQ(cat.size(), 2u);
  auto id = table.Find("identity");
  ASSERT_TRUE(id.ok());
  EXPECT_EQ(cat.at(0, 1), Entry{*id});
  EXPECT_TRUE(cat.empty(1, 0));
  EXPECT_TRUE(table.IsIdentity(*id));

  const GridFrame f = TreeFrame();
  const IfsMatrixExample tree = TreeMatrixExample();
  const VoxelSet want = VoxelsOf(Render(tree.maps, tree.matrix, {0, 1}, 11), f);
  const VoxelSet cat_det = VoxelsOf(Render(table.maps(), cat, {0, 1}, 12), f);
  const auto grids = ChaosVoxels(table.maps(), cat, {{0, 1}}, f, 1000000, 8);
  ASSERT_EQ(grids.size(), 1u);
  EXPECT_TRUE(Missing(grids[0], want, 1).empty());
  EXPECT_TRUE(Missing(want, grids[0], 1).empty());
  EXPECT_TRUE(Missing(cat_det, want, 1).empty());
  EXPECT_TRUE(Missing(want, cat_det, 1).empty());

  // Links out of range are refused with the expression's name.
  auto bad = EvaluateMatrixExpr(*MatrixConcatenation(crown, trunk, {{0, 3}}), table);
  EXPECT_EQ(bad.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(std::string(bad.status().message()), HasSubstr("concat(crown, trunk, 0->3)"));
}

TEST(Operations, MismatchedSizesAreRefused) {
  MapTable table(SixMaps());
  auto a = MatrixLeaf("a", IfsMatrix(2));
  auto b = MatrixLeaf("b", IfsMatrix(3));
  auto r = EvaluateMatrixExpr(*MatrixLabeled("mix", MatrixUnion({a, b})), table);
  EXPECT_EQ(r.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(std::string(r.status().message()), HasSubstr("'mix'"));
  auto bad_ref = MatrixLeaf("c", *IfsMatrix::FromRows({{{7}}}));
  r = EvaluateMatrixExpr(*bad_ref, table);
  EXPECT_THAT(std::string(r.status().message()), HasSubstr("refers to map 7"));
}

// ---------------------------------------------------------------------------
// Limits and reports

TEST(Expansion, ReportsSizesAndRefusesLargeResults) {
  MapTable table(SixMaps());
  Rng rng(5, 0);
  auto big = MatrixLeaf("big", RandomMatrix(rng, 20, 6));
  auto small = MatrixLeaf("small", RandomMatrix(rng, 2, 6));
  std::vector<ExpansionStep> report;
  auto ok = EvaluateMatrixExpr(*MatrixTensorProduct(big, small), table, {}, &report);
  ASSERT_TRUE(ok.ok()) << ok.status();
  ASSERT_EQ(report.size(), 3u);
  EXPECT_EQ(report[0].expression, "big");
  EXPECT_EQ(report[0].depth, 1);
  EXPECT_EQ(report[0].size, 20u);
  EXPECT_EQ(report[2].expression, "tensor_product(big, small)");
  EXPECT_EQ(report[2].depth, 0);
  EXPECT_EQ(report[2].size, 40u);
  EXPECT_EQ(report[2].map_references, ok->MapReferences());

  ExpansionLimits limits;
  limits.max_size = 256;
  auto too_big = EvaluateMatrixExpr(
      *MatrixUnion({big, MatrixLabeled("huge", MatrixTensorProduct(big, big))}), table, limits);
  EXPECT_EQ(too_big.status().code(), absl::StatusCode::kResourceExhausted);
  EXPECT_THAT(std::string(too_big.status().message()), HasSubstr("'huge'"));
  EXPECT_THAT(std::string(too_big.status().message()), HasSubstr("400 x 400"));

  limits = {};
  limits.max_map_references = 1000;
  auto too_many = EvaluateMatrixExpr(*MatrixTensorProduct(big, small), table, limits);
  EXPECT_EQ(too_many.status().code(), absl::StatusCode::kResourceExhausted);
  EXPECT_THAT(std::string(too_many.status().message()), HasSubstr("tensor_product(big, small)"));

  // Compositions stop when the map table would overflow.
  limits = {};
  limits.max_table_maps = 20;
  auto composed = EvaluateMatrixExpr(*MatrixComposition({big, big}), table, limits);
  EXPECT_EQ(composed.status().code(), absl::StatusCode::kResourceExhausted);
}

TEST(Expansion, DeterministicRenderRefusesTooManyPoints) {
  const IfsMatrixExample tree = TreeMatrixExample();
  DeterministicRenderOptions options;
  options.max_points = 1000;
  auto r = RenderComponentDeterministic(tree.maps, tree.matrix, {0, 1}, 12, options);
  EXPECT_EQ(r.status().code(), absl::StatusCode::kResourceExhausted);
}

// ---------------------------------------------------------------------------
// Chains with a state that has no predecessor

TEST(Chain, SourceStateRestarts) {
  // [[{}, {f}], [{}, {g1, g2}]]: A_01 = f(A_11), where A_11 is the unit
  // segment on x and f moves it to y = 1 at half length. State 0 has no
  // predecessor, so the walker can only leave it by a restart.
  std::vector<PointMap> maps = {
      Affine("f", Affine3::Translate({0, 1, 0}) * Half()),
      Affine("g1", Half()),
      Affine("g2", Affine3::Translate({0.5, 0, 0}) * Half()),
  };
  const IfsMatrix m = *IfsMatrix::FromRows({{{}, {0}}, {{}, {1, 2}}});
  GridFrame f;
  f.resolution = {64, 64, 1};
  f.bounds = {{-0.5, -0.5, -0.5}, {1.5, 1.5, 0.5}};
  auto chain = BuildComponentChain(maps, m, {{0, 1}, {1, 1}}, "m");
  ASSERT_TRUE(chain.ok()) << chain.status();
  for (size_t s = 0; s < chain->states.size(); ++s) {
    if (chain->states[s].kind != ComponentChain::Kind::kLive || chain->states[s].row != 0) continue;
    // Its only way on is the restart into the trunk's warm-up.
    ASSERT_EQ(chain->chain.states[s].transitions.size(), 1u);
    const auto& next = chain->states[chain->chain.states[s].transitions[0].next_state];
    EXPECT_EQ(next.kind, ComponentChain::Kind::kWarmup);
    EXPECT_EQ(next.level, 0u);
  }
  auto run = RunChainReference(maps, chain->chain, f, 200000, 30, 2);
  ASSERT_TRUE(run.ok()) << run.status();
  ASSERT_EQ(run->labels.size(), 2u);
  const VoxelSet top = VoxelsOf(run->labels[0]), bottom = VoxelsOf(run->labels[1]);
  const Vec3 h = f.VoxelSize();
  for (const Voxel& v : top)
    EXPECT_LE(SegmentDistance(f.VoxelCenter({v[0], v[1], v[2]}), {0, 1, 0}, {0.5, 1, 0}),
              Length(h));
  for (const Voxel& v : bottom)
    EXPECT_LE(SegmentDistance(f.VoxelCenter({v[0], v[1], v[2]}), {0, 0, 0}, {1, 0, 0}), Length(h));
  EXPECT_GE(top.size(), 16u);  // half a unit at 32 voxels per unit
  EXPECT_GE(bottom.size(), 32u);
  // Component (0, 0) is empty.
  EXPECT_FALSE(BuildComponentChain(maps, m, {{0, 0}}, "m").ok());
}

class StopAtOnce : public Interrupter {
 public:
  bool WasInterrupted(uint64_t, uint64_t) override { return true; }
};

TEST(Chain, ReferenceRunIsInterruptibleAndDeterministic) {
  const IfsMatrixExample tree = TreeMatrixExample();
  auto chain = BuildComponentChain(tree.maps, tree.matrix, {{0, 1}}, "tree");
  ASSERT_TRUE(chain.ok());
  StopAtOnce stop;
  auto r = RunChainReference(tree.maps, chain->chain, TreeFrame(), 100000, 10, 1, &stop);
  EXPECT_EQ(r.status().code(), absl::StatusCode::kCancelled);
  auto a = RunChainReference(tree.maps, chain->chain, TreeFrame(), 50000, 10, 1);
  auto b = RunChainReference(tree.maps, chain->chain, TreeFrame(), 50000, 10, 1);
  ASSERT_TRUE(a.ok() && b.ok());
  EXPECT_EQ(a->plotted, b->plotted);
  EXPECT_EQ(VoxelsOf(a->counts), VoxelsOf(b->counts));
  // Explicit weights are validated.
  ComponentChainOptions options;
  options.map_weights = {1, 1, 0, 1};
  EXPECT_THAT(std::string(BuildComponentChain(tree.maps, tree.matrix, {{0, 1}}, "tree", options)
                              .status()
                              .message()),
              HasSubstr("'T3'"));
}

}  // namespace
}  // namespace nimbus
