// The key a plotted point becomes, composed from the engine's public
// pieces one point at a time: the oracle for the flame plot kernels
// (core/chaos/flame_plot.h).
#pragma once

#include <cstdint>
#include <optional>

#include "core/base/geometry.h"
#include "core/chaos/chaos_game.h"
#include "core/grid/count_grid.h"

namespace nimbus::testing {

/// The CountGrid key (voxel and colour bits) of a finite point `q` with
/// colour coordinate `col` for a job of `p` counting into `grid`, without
/// arcs or splatting; nullopt when it misses the grid or the picture.
/// Voxel coordinates are (q - min) * (1 / voxel size) truncated; pictures
/// go through ImagePlane::Project and ImagePlane::Voxel.
std::optional<uint64_t> ExpectedPlotKey(const ChaosGameParams& p, const CountGrid& grid, Vec3 q,
                                        double col);

}  // namespace nimbus::testing
