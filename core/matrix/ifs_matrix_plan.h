// @brief The plan of an IFS-matrix job (chaos_game.matrices): the run of
// the whole selected object, plus what the component grid and the reports
// need. Protobuf-free; made by the spec converter, run by the matrix runner.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "core/chaos/chaos_game.h"
#include "core/matrix/component_grid.h"
#include "core/matrix/ifs_matrix.h"

namespace nimbus {

/// @brief A validated IFS-matrix job.
struct IfsMatrixPlan {
  /// The whole selection as one chaos game (a chain over the expanded map
  /// table, or a plain IFS for a 1x1 matrix). Without a component grid the
  /// job is exactly this run.
  ChaosGameParams run;
  /// Every map of the expanded expression (base maps, then composed ones).
  std::vector<PointMap> maps;
  /// The rendered (expanded) matrix, indexing `maps`.
  IfsMatrix matrix;
  /// Selected components; a component's label is its index here.
  std::vector<Component> selection;
  /// Expansion report: every named expression and the render expression.
  std::vector<ExpansionStep> expansion;
  /// Size of the chain of the whole selection (0 for the 1x1 fast path,
  /// which runs as a plain IFS).
  size_t chain_states = 0;
  /// Component grid requested (kNone: density only).
  ComponentGridType component_grid = ComponentGridType::kNone;
  /// With a component grid: one engine run per selected component, each
  /// plotting only that component (same frame, iterations split evenly,
  /// seeds derived from the job's seed). Empty otherwise.
  std::vector<ChaosGameParams> component_runs;
};

}  // namespace nimbus
