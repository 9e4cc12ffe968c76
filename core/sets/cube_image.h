// The image of one voxel cube under a map known only at its eight corners,
// filled as six tetrahedra: the gap filling of the median
// (docs/condensation.md#left-median-and-median).
#pragma once

#include <algorithm>

#include "absl/functional/function_ref.h"
#include "core/base/geometry.h"
#include "core/grid/voxel_set.h"

namespace nimbus {

/// @brief Box spanned by eight voxels (the images of a cube's corners),
/// clipped to the lattice of `resolution`. Inline: the gap filling calls it
/// for every candidate cube.
inline VoxelBox CubeImageBox(const Int3 (&img)[8], Int3 resolution) {
  Int3 lo = img[0], hi = img[0];
  for (int i = 1; i < 8; ++i) {
    lo = {std::min(lo.x, img[i].x), std::min(lo.y, img[i].y), std::min(lo.z, img[i].z)};
    hi = {std::max(hi.x, img[i].x), std::max(hi.y, img[i].y), std::max(hi.z, img[i].z)};
  }
  return {{std::max(lo.x, 0), std::max(lo.y, 0), std::max(lo.z, 0)},
          {std::min(hi.x, resolution.x - 1), std::min(hi.y, resolution.y - 1),
           std::min(hi.z, resolution.z - 1)}};
}

/// @brief True when every voxel of `box` is set in `out`. Safe while other
/// threads add bits through atomic ORs (a bit seen clear too early only
/// costs a fill that changes nothing).
bool BoxFilled(const VoxelSet& out, const VoxelBox& box);

/// @brief Sets every voxel of `box` whose index lies in one of the six
/// closed tetrahedra {0,1,3,7}, {0,1,5,7}, {0,2,3,7}, {0,2,6,7}, {0,4,5,7},
/// {0,4,6,7} of the corner images img[c] (corner c of the cube is
/// (c & 1, (c >> 1) & 1, c >> 2)), with exact integer orientation tests, so
/// tetrahedra sharing a face leave no crack. Flat tetrahedra add nothing.
/// Coordinates must be below 2^16. Bits are added with atomic ORs, so
/// several threads may fill into one set. `worth` is asked once, at the
/// first voxel the fill would add (never when it would add none): when it
/// says no, nothing is added. It lets the caller defer a costly check (the
/// gap filling's coherence tests) until it can matter, and makes the box
/// scan serve as the BoxFilled test too instead of a second pass.
void FillCubeImage(const Int3 (&img)[8], const VoxelBox& box, VoxelSet& out,
                   absl::FunctionRef<bool()> worth = [] { return true; });

}  // namespace nimbus
