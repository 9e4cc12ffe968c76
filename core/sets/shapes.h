// Built-in condensation sets: analytic solids and "random balls inside a
// shape", the second sketch of the reference description's cloud bull
// (docs/algorithms.md#random-iteration-on-sets).
#pragma once

#include <cstdint>

#include "absl/status/statusor.h"
#include "core/base/geometry.h"
#include "core/grid/voxel_set.h"

namespace nimbus {

// A voxel belongs to a shape when its centre lies inside (boundary
// included). Centres, radii and boxes are in world units.

/// @brief Solid ball.
absl::StatusOr<VoxelSet> SphereSet(const GridFrame& frame, Vec3 centre, double radius);

/// @brief Solid axis-aligned box.
absl::StatusOr<VoxelSet> BoxSet(const GridFrame& frame, const Bounds& box);

/// @brief Solid torus around `axis` through `centre`: points within
/// `minor_radius` of the circle of radius `major_radius`.
absl::StatusOr<VoxelSet> TorusSet(const GridFrame& frame, Vec3 centre, Vec3 axis,
                                  double major_radius, double minor_radius);

struct RandomBallsOptions {
  int count = 24;
  double min_radius = 0.05;  // world units
  double max_radius = 0.15;  // world units
  uint64_t seed = 1;
  /// Keep only the parts of the balls inside the region.
  bool clip_to_region = false;
};

/// @brief `count` balls whose centres are uniform over the members of
/// `region` (a uniformly chosen member voxel, jittered inside it) and whose
/// radii are uniform in [min_radius, max_radius]. Same seed, same balls.
absl::StatusOr<VoxelSet> RandomBallsInside(const VoxelSet& region, const GridFrame& frame,
                                           const RandomBallsOptions& options);

}  // namespace nimbus
