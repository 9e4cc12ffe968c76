// @brief A jelly frame's points and what they accumulate into. Vector
// Recursive Rendering (VRR) gives every composition of the maps to a fixed
// depth applied to the start points, in a fixed order; the chaos-game
// alternative replays the same random addresses every frame. Either way
// leaf k of one frame is leaf k of the next, so finite differences of leaf
// positions are velocities.
#pragma once

#include <cstdint>
#include <vector>

#include "absl/status/statusor.h"
#include "core/base/geometry.h"
#include "core/base/interrupter.h"
#include "core/grid/count_grid.h"
#include "core/io/vdb_io.h"
#include "core/jelly/jelly_plan.h"

namespace nimbus {

/// maps^depth × start points, or UINT64_MAX when it overflows.
uint64_t VrrLeafCount(uint64_t maps, uint32_t depth, uint64_t start_points);

/// Leaves of `render` for this frame's `maps` into `out` (resized). VRR
/// leaf index = word (i1 … iN, i1 most significant) × starts + start, leaf =
/// M_i1·…·M_iN(start). Chaos game: `render.points` points from fixed random
/// streams. Multi-threaded (TBB); bitwise the same for any thread count.
/// CANCELLED when interrupted (polled every ~64k leaves).
absl::Status JellyLeaves(const std::vector<Affine3>& maps, const JellyRender& render,
                         std::vector<Vec3>& out, Interrupter* interrupter);

/// Moves leaves below y = height up onto it; returns how many moved.
uint64_t ClampToGround(std::vector<Vec3>& leaves, double height);

/// @brief A frame's accumulation: counts per voxel and, when asked, the
/// mean leaf velocity per voxel (a Vec3 field named "v").
struct JellyFrameGrids {
  CountGrid counts;
  Vec3Field velocity;
  /// Leaves outside the grid's bounds.
  uint64_t outside = 0;
};

/// Counts `leaves` into `frame` and, when `velocity`, writes v = (leaf -
/// prev) / seconds averaged over each voxel's leaves (zero where `prev` does
/// not hold as many leaves: the first frame). Deterministic: voxels sum
/// their leaves in leaf order. CANCELLED when interrupted (polled every
/// ~64k leaves).
absl::StatusOr<JellyFrameGrids> AccumulateLeaves(const std::vector<Vec3>& leaves,
                                                 const std::vector<Vec3>& prev, double seconds,
                                                 const GridFrame& frame, bool velocity,
                                                 Interrupter* interrupter = nullptr);

}  // namespace nimbus
