// Test oracles for IFS matrices: plain, unoptimised reference algorithms the
// tests and the benchmark check the matrix engine against, and the worked
// example of docs/algorithms.md#worked-example-the-tree. They use the matrix
// types as data only: none of the engine's expansion, chain or sampling code
// runs in here.
#pragma once

#include <cstdint>
#include <vector>

#include "absl/status/statusor.h"
#include "core/base/geometry.h"
#include "core/base/interrupter.h"
#include "core/chaos/chaos_game.h"
#include "core/chaos/point_map.h"
#include "core/grid/count_grid.h"
#include "core/matrix/ifs_matrix.h"

namespace nimbus::testing {

struct DeterministicRenderOptions {
  Vec3 start;  // K: the point every word is applied to
  uint64_t max_points = uint64_t{1} << 22;
  uint64_t seed = 0;  // for random variations only
};

/// @brief Deterministic algorithm for one component: applies every word of
/// (H^depth)_ij (all paths i -> j of exactly `depth` edges) to the start
/// point, innermost map first. Computed backwards from j, keeping only rows
/// that row i reaches in the remaining number of steps, so every
/// intermediate point ends up in the output. ResourceExhausted when the
/// word count exceeds max_points (checked before any map is applied).
absl::StatusOr<std::vector<Vec3>> RenderComponentDeterministic(
    const std::vector<PointMap>& maps, const IfsMatrix& m, Component c, int depth,
    const DeterministicRenderOptions& options = {});

/// Counts from the reference chaos game.
struct ReferenceChaosResult {
  explicit ReferenceChaosResult(Int3 resolution) : counts(resolution) {}
  CountGrid counts;               // every plotted point
  std::vector<CountGrid> labels;  // by ChainState::label (labels >= 0)
  uint64_t plotted = 0;           // points counted (inside the frame)
  uint64_t outside = 0;
  uint64_t reseeded = 0;
};

/// @brief Single-threaded, unoptimised chaos game over a MarkovChain, with
/// the same step rule as the engine: draw a transition of the current
/// state, apply its map, move, then plot if the new state is plotted. The
/// walker starts at a random point of the frame in chain.start_state and
/// takes `warmup` unplotted steps first (and again after a non-finite
/// point). Transitions are drawn by inverting the cumulative distribution,
/// not by the engine's alias tables, so its random stream is its own.
absl::StatusOr<ReferenceChaosResult> RunChainReference(const std::vector<PointMap>& maps,
                                                       const MarkovChain& chain,
                                                       const GridFrame& frame, uint64_t iterations,
                                                       uint32_t warmup, uint64_t seed,
                                                       Interrupter* interrupter = nullptr);

/// Maps and matrix of an example; maps are in table order.
struct IfsMatrixExample {
  std::vector<PointMap> maps;
  IfsMatrix matrix;
};

/// @brief The 3D tree of docs/algorithms.md#worked-example-the-tree: maps
/// T1..T4 (indices 0..3) and H = [[{T3, T4}, {T1, T2}], [{}, {T1, T2}]]. Component (1, 1)
/// is the trunk from (0,0,0) to (0,1,0), (0, 0) the canopy A(T3, T4), and
/// (0, 1) the branching tree.
IfsMatrixExample TreeMatrixExample();

}  // namespace nimbus::testing
