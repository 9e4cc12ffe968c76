// Scattered counts with colour, for tests of the VDB writers.
#pragma once

#include <cstdint>

#include "core/base/geometry.h"
#include "core/grid/count_grid.h"

namespace nimbus::testing {

/// `n` keys with random colour over a grid of resolution `r`: every
/// seventh voxel is hit 1 to 40 times, the rest once, so densities spread.
CountGrid ScatterColorCounts(Int3 r, int n, uint32_t seed);

}  // namespace nimbus::testing
