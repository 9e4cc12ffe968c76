// @brief Jelly scenes shared by tests and benchmarks.
#pragma once

#include <cstdint>

#include "core/jelly/jelly_plan.h"

namespace nimbus::testing {

/// The reference description's scene: a Sierpinski tetrahedron of four
/// half-scale maps joined by six springs (k = 60, b = 0.6), falling onto
/// the ground y = 0; 24 fps, 10 substeps, 48 frames, VRR to `depth`.
JellyPlan SierpinskiJelly(uint32_t depth);

}  // namespace nimbus::testing
