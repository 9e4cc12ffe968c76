// Chaos-game throughput on the tree IFS matrix
// (docs/algorithms.md#worked-example-the-tree) against a plain IFS with the
// same four maps, on the same grid, one thread.
// The chain adds per-state alias tables and unplotted warm-up / restart
// steps; the summary line states the overhead in plotted updates per second.
#include <benchmark/benchmark.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <map>
#include <string>
#include <vector>

#include "core/chaos/chaos_game.h"
#include "core/matrix/ifs_matrix.h"
#include "tests/support/matrix_oracles.h"

namespace nimbus {
namespace {

using ::nimbus::testing::IfsMatrixExample;
using ::nimbus::testing::TreeMatrixExample;

constexpr uint64_t kIterations = uint64_t{1} << 24;

// The frame of examples/tree.json: the tree lies in the x = 0 plane.
GridFrame TreeFrame() {
  return {{9, 256, 240}, {{-0.0325, -0.025, -0.8671875}, {0.0325, 1.825, 0.8671875}}};
}

ChaosGameParams PlainParams() {
  IfsMatrixExample ex = TreeMatrixExample();
  ChaosGameParams p;
  p.ifs.maps = ex.maps;
  p.ifs.probabilities = DeterminantProbabilities(ex.maps, 0.01);
  p.frame = TreeFrame();
  p.iterations = kIterations;
  p.seed = 3;
  return p;
}

ChaosGameParams MatrixParams(const std::vector<Component>& selection) {
  IfsMatrixExample ex = TreeMatrixExample();
  auto chain = BuildComponentChain(ex.maps, ex.matrix, selection, "H_tree");
  if (!chain.ok()) {
    std::fprintf(stderr, "%s\n", std::string(chain.status().message()).c_str());
    std::abort();
  }
  ChaosGameParams p = PlainParams();
  p.chain = std::move(chain->chain);
  return p;
}

// Long-run share of steps that are plotted, from the chain's stationary
// distribution (lazy power iteration, so periodic warm-up rings converge).
// The engine reports plotted steps only; dividing by this share gives every
// map application, plotted or not.
double PlottedShare(const ChaosGameParams& params) {
  if (!params.chain) return 1.0;
  const MarkovChain& chain = *params.chain;
  const size_t n = chain.states.size();
  std::vector<double> pi(n, 1.0 / double(n)), next(n);
  for (int it = 0; it < 20000; ++it) {
    for (size_t s = 0; s < n; ++s) next[s] = 0.5 * pi[s];
    for (size_t s = 0; s < n; ++s) {
      const ChainState& st = chain.states[s];
      for (size_t t = 0; t < st.transitions.size(); ++t)
        next[st.transitions[t].next_state] += 0.5 * pi[s] * st.probabilities[t];
    }
    pi.swap(next);
  }
  double plotted = 0;
  for (size_t s = 0; s < n; ++s)
    if (chain.states[s].plotted) plotted += pi[s];
  return plotted;
}

struct Rate {
  double plotted = 0;  // plotted points per second
  double steps = 0;    // map applications per second
  double share = 1;    // plotted share of the steps
};

std::map<std::string, Rate>& Rates() {
  static std::map<std::string, Rate> rates;
  return rates;
}

void Run(benchmark::State& state, const ChaosGameParams& params, const std::string& name) {
  uint64_t plotted = 0;
  double seconds = 0;
  for (auto _ : state) {
    auto game = ChaosGame::Create(params, 1);
    if (!game.ok()) {
      state.SkipWithError(std::string(game.status().message()).c_str());
      return;
    }
    // Process CPU time: the machine is shared, and one engine thread's CPU
    // time is what the two runs differ in.
    const std::clock_t start = std::clock();
    if (!(*game)->Run(nullptr).ok()) state.SkipWithError("run failed");
    seconds += double(std::clock() - start) / CLOCKS_PER_SEC;
    plotted += (*game)->stats().iterations_done;
    benchmark::DoNotOptimize((*game)->partial_counts().data());
  }
  state.SetItemsProcessed(int64_t(plotted));
  const double rate = double(plotted) / std::max(seconds, 1e-9);
  const double share = PlottedShare(params);
  state.counters["Mupdates/s"] = rate / 1e6;
  state.counters["Msteps/s"] = rate / share / 1e6;
  state.counters["plotted_share"] = share;
  Rates()[name] = {rate, rate / share, share};
}

void BM_PlainIfs4Maps(benchmark::State& state) { Run(state, PlainParams(), "plain"); }
void BM_TreeMatrixA12(benchmark::State& state) { Run(state, MatrixParams({{0, 1}}), "A12"); }
void BM_TreeMatrixA11A12A22(benchmark::State& state) {
  Run(state, MatrixParams({{0, 0}, {0, 1}, {1, 1}}), "A11+A12+A22");
}

BENCHMARK(BM_PlainIfs4Maps)->Unit(benchmark::kMillisecond)->MinTime(2.0);
BENCHMARK(BM_TreeMatrixA12)->Unit(benchmark::kMillisecond)->MinTime(2.0);
BENCHMARK(BM_TreeMatrixA11A12A22)->Unit(benchmark::kMillisecond)->MinTime(2.0);

}  // namespace
}  // namespace nimbus

int main(int argc, char** argv) {
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  const auto& rates = nimbus::Rates();
  const auto plain = rates.find("plain");
  if (plain == rates.end()) return 0;
  const nimbus::Rate& p = plain->second;
  for (const auto& [name, r] : rates) {
    if (name == "plain") continue;
    std::printf(
        "tree matrix %s: %.1f M plotted updates/s vs plain IFS (4 maps) %.1f M/s: "
        "overhead %+.1f%% (target within 15%%)\n",
        name.c_str(), r.plotted / 1e6, p.plotted / 1e6, 100.0 * (p.plotted / r.plotted - 1.0));
    std::printf(
        "  of which structural: %.1f%% of the chain's steps are unplotted (warm-up, "
        "restarts, unselected states); per map application %.1f M/s: engine overhead "
        "%+.1f%%\n",
        100.0 * (1.0 - r.share), r.steps / 1e6, 100.0 * (p.steps / r.steps - 1.0));
  }
  return 0;
}
