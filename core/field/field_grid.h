// @brief Evaluates a fractal field on a regular grid of space points at one
// time, fast: per mesh, node values are hashed once per lattice plane and the
// interpolation runs as separable passes along x, then y, then z (the
// pseudo n-cubic as two channels, value and derivative), over x-slabs in
// parallel (TBB). A rotated mesh, or a mapping that mixes axes, falls back
// to the point evaluator for that mesh. Every sample's value depends only on
// its own position, so results are the same bytes for any thread count.
#pragma once

#include <array>
#include <cstddef>

#include "absl/status/status.h"
#include "core/base/interrupter.h"
#include "core/field/fractal_field.h"

namespace nimbus {

/// @brief Sample (i, j, k) sits at space point origin + (i, j, k) * step.
/// Axes beyond the mapping's space_dims must have count 1.
struct FieldGrid {
  std::array<int, 3> count{1, 1, 1};
  std::array<double, 3> origin{0, 0, 0};
  std::array<double, 3> step{1, 1, 1};
  double time = 0;

  size_t size() const { return size_t(count[0]) * size_t(count[1]) * size_t(count[2]); }
};

/// Writes the field at every sample of `grid` into `out` (grid.size()
/// floats, x slowest, z fastest). CancelledError when interrupted (polled
/// about every x row of every mesh, a few ms at most).
absl::Status EvaluateFieldGrid(const FractalField& field, const FieldGrid& grid, float* out,
                               Interrupter* interrupter = nullptr);

}  // namespace nimbus
