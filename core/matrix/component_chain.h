// The chaos game for selected components of an IFS matrix: the Markov chain
// that walks the matrix's graph backwards (docs/ifs_matrices.md).
#pragma once

#include <cstddef>
#include <cstdint>
#include <string_view>
#include <vector>

#include "absl/status/statusor.h"
#include "core/chaos/chaos_game.h"
#include "core/chaos/point_map.h"
#include "core/matrix/ifs_matrix_core.h"

namespace nimbus {

struct ComponentChainOptions {
  /// Determinant rule: a transition's weight is |det pre| of its map, raised
  /// to at least floor * (largest |det| among the matrix's maps).
  double probability_floor = 0.01;
  /// Optional explicit weights by map-table index (all > 0); overrides the
  /// determinant rule when non-empty.
  std::vector<double> map_weights;
  /// Unplotted steps inside a sink class after every (re)start; 0 = derived
  /// from the contraction: ceil(log(warmup_tolerance) / log(c_max)).
  uint32_t warmup_steps = 0;
  double warmup_tolerance = 1e-5;
  /// Used when c_max is unknown (nonlinear maps) or >= 1.
  uint32_t fallback_warmup_steps = 64;
  /// Per-step chance of a restart from states that need one; 0 = 1 / (2 L)
  /// for the longest warm-up L.
  double restart_probability = 0;
  /// ResourceExhausted beyond this many chain states.
  size_t max_states = size_t{1} << 20;
};

/// @brief A MarkovChain for a selection of components plus, per chain
/// state, where it comes from.
struct ComponentChain {
  enum class Kind {
    kLive,     // a matrix state of a column block; plotted iff selected
    kWarmup,   // unplotted copy of a sink-class state, `level` steps in
    kRestart,  // unplotted hub that picks the sink class to re-enter
  };
  struct StateInfo {
    Kind kind = Kind::kLive;
    uint32_t row = 0;    // matrix state (live and warm-up states)
    uint32_t col = 0;    // column j of the block (live and warm-up states)
    uint32_t level = 0;  // warm-up copies only
  };
  MarkovChain chain;
  std::vector<StateInfo> states;  // parallel to chain.states
};

/// @brief Builds the chaos game on the graph for `selection` (labels are
/// selection indices).
///
/// Why backwards: a point of A_sj is refined by prepending a map, f(A_sj)
/// is part of A_rj for f in H_rs. So a walker holding (p, s) draws a
/// predecessor edge r -> s with map f, sets p = f(p) and moves to r. After
/// many steps p is f1 o ... o fm (p0) for a path r -> ... -> s0, whose
/// prefix is what fixes the point.
///
/// Construction, one block per selected column j:
///  * live states: S_j = { r : lim R^k has (r, j) } (rows whose component
///    in column j exists), further restricted to the states a selected row
///    reaches (others never lead back to a plotted state). Each has every
///    predecessor edge inside the block as a transition, weighted by the
///    map weight and normalised per state. Plotted iff (r, j) is selected.
///  * warm-up: the walk's tail is its innermost part, and any infinite path
///    in S_j can be approximated by one that ends in a *sink* strongly
///    connected class of the block. So every (re)start enters L unplotted
///    copies of a sink class (walking only its internal edges) and then its
///    live states; L is chosen so c_max^L < warmup_tolerance.
///  * restarts: walking backwards the walker drifts to source-side classes
///    and would stay there (e.g. the tree's canopy state), so live states
///    outside sink classes, states without predecessors, and every live
///    state when there are several blocks restart with some probability
///    into a warm-up, sink classes chosen uniformly over all blocks (through
///    one hub state when there are several, to keep transitions few).
///  * the walk starts in the first warm-up, so it needs no engine warm-up.
///
/// Errors (InvalidArgument naming `name`): periodic matrix, empty or
/// out-of-range component, bad map index or weights.
absl::StatusOr<ComponentChain> BuildComponentChain(const std::vector<PointMap>& maps,
                                                   const IfsMatrix& m,
                                                   const std::vector<Component>& selection,
                                                   std::string_view name,
                                                   const ComponentChainOptions& options = {});

}  // namespace nimbus
