#include "tests/support/matrix_oracles.h"

#include <algorithm>
#include <cmath>
#include <string>
#include <utility>

#include "absl/strings/str_cat.h"
#include "core/base/random.h"

namespace nimbus::testing {
namespace {

std::string Cell(Component c) { return absl::StrCat("(", c.row, ", ", c.col, ")"); }

// The oracle's own input check, so it does not lean on the engine's.
absl::Status CheckMapIndices(const std::vector<PointMap>& maps, const IfsMatrix& m) {
  for (uint32_t i = 0; i < m.size(); ++i)
    for (uint32_t j = 0; j < m.size(); ++j)
      for (uint32_t f : m.at(i, j))
        if (f >= maps.size())
          return absl::InvalidArgumentError(absl::StrCat("rendered matrix entry ", Cell({i, j}),
                                                         " refers to map ", f, ", but there are ",
                                                         maps.size(), " maps"));
  return absl::OkStatus();
}

// reach[t][s]: row `from` reaches state s in exactly t steps.
std::vector<std::vector<char>> Reach(const IfsMatrix& m, uint32_t from, int depth) {
  const uint32_t n = m.size();
  std::vector<std::vector<char>> reach(depth + 1, std::vector<char>(n, 0));
  reach[0][from] = 1;
  for (int t = 1; t <= depth; ++t)
    for (uint32_t r = 0; r < n; ++r)
      if (reach[t - 1][r])
        for (uint32_t s = 0; s < n; ++s)
          if (!m.empty(r, s)) reach[t][s] = 1;
  return reach;
}

// Number of words the render will produce, as a double (it may be huge).
double WordCount(const IfsMatrix& m, Component c, int depth,
                 const std::vector<std::vector<char>>& reach) {
  const uint32_t n = m.size();
  std::vector<double> count(n, 0.0), next(n);
  count[c.col] = reach[depth][c.col] ? 1.0 : 0.0;
  for (int t = 1; t <= depth; ++t) {
    std::fill(next.begin(), next.end(), 0.0);
    for (uint32_t r = 0; r < n; ++r) {
      if (!reach[depth - t][r]) continue;
      for (uint32_t s = 0; s < n; ++s) next[r] += double(m.at(r, s).size()) * count[s];
    }
    std::swap(count, next);
  }
  return count[c.row];
}

// Cumulative probabilities of every state's transitions; InvalidArgument
// for a chain the walk cannot run on.
absl::StatusOr<std::vector<std::vector<double>>> CumulativeTables(const std::vector<PointMap>& maps,
                                                                  const MarkovChain& chain) {
  if (chain.states.empty() || chain.start_state >= chain.states.size())
    return absl::InvalidArgumentError("the chain has no states or a missing start state");
  std::vector<std::vector<double>> tables;
  for (size_t s = 0; s < chain.states.size(); ++s) {
    const ChainState& st = chain.states[s];
    if (st.transitions.empty() || st.transitions.size() != st.probabilities.size())
      return absl::InvalidArgumentError(
          absl::StrCat("chain state ", s, " needs transitions with one probability each"));
    std::vector<double> cumulative;
    double total = 0;
    for (size_t t = 0; t < st.transitions.size(); ++t) {
      if (st.transitions[t].map >= maps.size() ||
          st.transitions[t].next_state >= chain.states.size())
        return absl::InvalidArgumentError(
            absl::StrCat("chain state ", s, " has a transition to a missing map or state"));
      if (!(st.probabilities[t] >= 0))
        return absl::InvalidArgumentError(
            absl::StrCat("chain state ", s, " has a negative probability"));
      total += st.probabilities[t];
      cumulative.push_back(total);
    }
    if (std::fabs(total - 1.0) > 1e-9)
      return absl::InvalidArgumentError(
          absl::StrCat("chain state ", s, " probabilities sum to ", total, ", not 1"));
    tables.push_back(std::move(cumulative));
  }
  return tables;
}

// Index of the first cumulative weight above u (u in [0, 1)); the last one
// when rounding leaves the total a hair below u.
size_t Pick(const std::vector<double>& cumulative, double u) {
  const size_t i = std::upper_bound(cumulative.begin(), cumulative.end(), u) - cumulative.begin();
  return std::min(i, cumulative.size() - 1);
}

}  // namespace

absl::StatusOr<std::vector<Vec3>> RenderComponentDeterministic(
    const std::vector<PointMap>& maps, const IfsMatrix& m, Component c, int depth,
    const DeterministicRenderOptions& options) {
  const uint32_t n = m.size();
  if (c.row >= n || c.col >= n)
    return absl::InvalidArgumentError(
        absl::StrCat("component ", Cell(c), " is outside a matrix of size ", n));
  constexpr int kMaxDepth = 1 << 16;
  if (depth < 0 || depth > kMaxDepth)
    return absl::InvalidArgumentError(absl::StrCat("depth must be in [0, ", kMaxDepth, "]"));
  if (absl::Status s = CheckMapIndices(maps, m); !s.ok()) return s;

  const std::vector<std::vector<char>> reach = Reach(m, c.row, depth);
  // Word counts first, so an oversized render is refused before any work.
  const double words = WordCount(m, c, depth, reach);
  if (words > double(options.max_points))
    return absl::ResourceExhaustedError(
        absl::StrCat("rendering component ", Cell(c), " to depth ", depth, " needs ", words,
                     " points, above the limit of ", options.max_points));

  // pts[s] = (H^t)_{s j}(start) for the rows still useful after t steps.
  Rng rng(options.seed, 0);
  std::vector<std::vector<Vec3>> pts(n), fresh(n);
  if (reach[depth][c.col]) pts[c.col].push_back(options.start);
  for (int t = 1; t <= depth; ++t) {
    for (auto& v : fresh) v.clear();
    for (uint32_t r = 0; r < n; ++r) {
      if (!reach[depth - t][r]) continue;
      for (uint32_t s = 0; s < n; ++s)
        for (uint32_t f : m.at(r, s))
          for (const Vec3& p : pts[s]) fresh[r].push_back(maps[f].Apply(p, rng));
    }
    std::swap(pts, fresh);
  }
  return std::move(pts[c.row]);
}

absl::StatusOr<ReferenceChaosResult> RunChainReference(const std::vector<PointMap>& maps,
                                                       const MarkovChain& chain,
                                                       const GridFrame& frame, uint64_t iterations,
                                                       uint32_t warmup, uint64_t seed,
                                                       Interrupter* interrupter) {
  const Int3 res = frame.resolution;
  if (res.x <= 0 || res.y <= 0 || res.z <= 0)
    return absl::InvalidArgumentError("grid resolution must be positive on every axis");
  const Vec3 size = frame.bounds.Size();
  if (!(size.x > 0 && size.y > 0 && size.z > 0))
    return absl::InvalidArgumentError("grid bounds must have max > min on every axis");
  absl::StatusOr<std::vector<std::vector<double>>> tables = CumulativeTables(maps, chain);
  if (!tables.ok()) return tables.status();
  int32_t labels = 0;
  for (const ChainState& st : chain.states)
    if (st.plotted) labels = std::max(labels, st.label + 1);

  ReferenceChaosResult out(res);
  for (int32_t l = 0; l < labels; ++l) out.labels.emplace_back(res);
  Interrupter& intr = OrNull(interrupter);
  intr.Start("reference chaos game");
  Rng rng(seed, 0);
  const Bounds& b = frame.bounds;
  const Vec3 vs = frame.VoxelSize();
  Vec3 p;
  uint32_t state = 0;
  auto step = [&] {
    const ChainState& st = chain.states[state];
    const ChainTransition& t = st.transitions[Pick((*tables)[state], rng.Uniform())];
    p = maps[t.map].Apply(p, rng);
    state = t.next_state;
    return IsFinite(p);
  };
  auto random_point = [&] {
    return Vec3{rng.Uniform(b.min.x, b.max.x), rng.Uniform(b.min.y, b.max.y),
                rng.Uniform(b.min.z, b.max.z)};
  };
  auto restart = [&] {
    p = random_point();
    state = chain.start_state;
    for (uint32_t i = 0; i < warmup; ++i)
      if (!step()) {
        p = random_point();
        ++out.reseeded;
      }
  };
  restart();
  for (uint64_t it = 0; it < iterations; ++it) {
    if ((it & 0xffff) == 0 && intr.WasInterrupted(it, iterations)) {
      intr.End();
      return absl::CancelledError("reference chaos game interrupted");
    }
    if (!step()) {
      ++out.reseeded;
      restart();
      continue;
    }
    const ChainState& st = chain.states[state];
    if (!st.plotted) continue;
    const double fx = (p.x - b.min.x) / vs.x, fy = (p.y - b.min.y) / vs.y,
                 fz = (p.z - b.min.z) / vs.z;
    if (!(fx >= 0 && fx < res.x && fy >= 0 && fy < res.y && fz >= 0 && fz < res.z)) {
      ++out.outside;
      continue;
    }
    const int x = int(fx), y = int(fy), z = int(fz);
    out.counts.Add(x, y, z);
    if (st.label >= 0) out.labels[st.label].Add(x, y, z);
    ++out.plotted;
  }
  intr.End();
  return out;
}

IfsMatrixExample TreeMatrixExample() {
  const Affine3 half = Affine3::Scale({0.5, 0.5, 0.5});
  const Affine3 up = Affine3::Translate({0, 1, 0});
  IfsMatrixExample ex;
  ex.maps.resize(4);
  ex.maps[0].name = "T1";
  ex.maps[0].pre = half;
  ex.maps[1].name = "T2";
  ex.maps[1].pre = Affine3::Translate({0, 0.5, 0}) * half;
  ex.maps[2].name = "T3";
  ex.maps[2].pre = up * Affine3::Rotate({1, 0, 0}, 45) * half;
  ex.maps[3].name = "T4";
  ex.maps[3].pre = up * Affine3::Rotate({1, 0, 0}, -45) * half;
  for (int i = 0; i < 4; ++i) ex.maps[i].color = i / 3.0;
  ex.matrix = IfsMatrix(2);
  ex.matrix.Set(0, 0, {2, 3});
  ex.matrix.Set(0, 1, {0, 1});
  ex.matrix.Set(1, 1, {0, 1});
  return ex;
}

}  // namespace nimbus::testing
