// Independent measures of a volume read back from a VDB file, for the tests
// of the output conventions: world-space extents and moments through the
// grid's own transform, mass, and the active voxels a box filter leaves.
#pragma once

#include <cstdint>

#include "core/base/geometry.h"
#include "core/io/vdb_io.h"

namespace nimbus::testing {

/// World-space centres of the active (non-zero) voxels: their bounding box
/// and density-weighted mean.
struct WorldSpread {
  Bounds box{{1e300, 1e300, 1e300}, {-1e300, -1e300, -1e300}};
  Vec3 centroid;
  uint64_t active = 0;
};
WorldSpread ActiveWorldSpread(const DenseVolume& v);

/// Sum of the values times the voxel volume (|det| of the index-to-world map).
double Mass(const DenseVolume& v);

/// Active voxels left after grouping the non-zero voxels of `v` into f^3
/// blocks (a set of block coordinates).
uint64_t CoarseActiveVoxels(const DenseVolume& v, int f);
/// The same voxels and the 8^3 leaves (of the coarse lattice) they touch.
GridSupport CoarseSupport(const DenseVolume& v, int f);

}  // namespace nimbus::testing
