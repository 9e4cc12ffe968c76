// @brief The ways a spec gives a field's meshes and weights: a geometric
// series of cell sizes, weight rules (cell volume, ratio^H, explicit), and
// periodic axes, whose cells are snapped so that a whole number of them
// fills each period (docs/fractal_fields.md#meshes-and-weights).
#pragma once

#include <string>
#include <vector>

#include "absl/status/status.h"
#include "core/field/fractal_field.h"

namespace nimbus {

/// @brief Cells base_cell * ratio^k for k = 0..count-1. Unless `aligned`,
/// mesh k is offset by the fractional parts of k times an irrational per
/// axis, so no two lattices share nodes.
struct MeshSeries {
  FieldVec base_cell{1, 1, 1, 1};
  double ratio = 0.5;
  int count = 1;
  bool aligned = false;
};

std::vector<FieldMesh> ExpandMeshSeries(const MeshSeries& series, int dims);

enum class WeightRule {
  kCellVolume,  // p_k = amplitude * V_k / V_0, V = product of the cell sizes
  kPower,       // p_k = amplitude * (c_k / c_0)^H, c the geometric mean cell size
  kExplicit,    // p_k = explicit[k]
};

/// Sets every mesh's weight by `rule`. `explicit_weights` must have one
/// finite value per mesh for kExplicit.
absl::Status ApplyWeightRule(WeightRule rule, double amplitude, double hurst,
                             const std::vector<double>& explicit_weights, int dims,
                             std::vector<FieldMesh>& meshes);

/// For every axis with params.mapping.period[i] > 0: sets each mesh's
/// period_nodes[i] = max(1, round(period / cell)) and the cell to
/// period / period_nodes, so the lattice repeats exactly; snapped cells that
/// moved by more than 1e-9 relative are reported in `notes`.
void SnapCellsToPeriods(FractalFieldParams& params, std::vector<std::string>* notes);

}  // namespace nimbus
