// @brief Auto-framing: the grid box fitted to an attractor from a short
// deterministic pilot run (docs/images.md#auto-framing).
#pragma once

#include <cstdint>

#include "absl/status/statusor.h"
#include "core/base/geometry.h"
#include "core/base/interrupter.h"
#include "core/chaos/chaos_game.h"

namespace nimbus {

struct AutoFrameParams {
  double margin = 0.05;            // of the extent, per side
  uint64_t pilot_iterations = 1 << 20;
  double trim = 1e-4;              // fraction of points dropped per side
};

/// @brief Walks `params` (its IFS, final transform, arcs, seed and warm-up;
/// no chain) for `pilot_iterations` plotted steps on kWalkers walkers that
/// start in params.frame.bounds, and returns the box holding all plotted
/// points but the `trim` fraction on each side of each axis, grown by
/// `margin` times its extent per side. A flat axis gets the extent of the
/// largest one times 1e-3, so the box is never empty. Same spec, same box.
absl::StatusOr<Bounds> FitBounds(const ChaosGameParams& params, const AutoFrameParams& fit,
                                 Interrupter* interrupter);

}  // namespace nimbus
