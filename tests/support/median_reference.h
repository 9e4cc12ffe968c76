// A brute-force median for small voxel sets: the oracle the set-map tests
// compare LeftMedian, Median and the median map against.
#pragma once

#include <string>
#include <vector>

#include "core/base/geometry.h"
#include "core/grid/voxel_set.h"

namespace nimbus::testing {

/// @brief What a median may be. Voxels whose nearest point is tied between
/// several members may go to any of their midpoints, so an answer holds
/// `certain` plus at least one voxel of each `alternatives` list, and
/// nothing else.
struct ReferenceMedian {
  VoxelSet certain;
  std::vector<std::vector<Int3>> alternatives;
  bool exact() const { return alternatives.empty(); }
};

/// @brief D_A(B), or with `both_sides` M(A, B) = D_A(B) ∪ D_B(A), by
/// comparing every pair of voxels: each voxel of A \ B goes to the midpoint
/// with its nearest voxel of B (world distance, voxel size `h`), voxels of
/// A ∩ B stay. Where a coordinate sum is odd, bit i of `round_up` sends the
/// midpoint up along axis i, else down. No gap filling: compare with
/// bridge_max_jump = 0, or with sets where no two voxels touch by a face.
ReferenceMedian BruteForceMedian(const VoxelSet& a, const VoxelSet& b, Vec3 h, unsigned round_up,
                                 bool both_sides);

/// True when `got` is an answer `ref` allows; otherwise `why` names a voxel
/// that is wrong or missing.
bool Admits(const ReferenceMedian& ref, const VoxelSet& got, std::string* why = nullptr);

/// The roundings (0..7, bit i for axis i) whose brute-force median admits
/// `got`.
std::vector<unsigned> AdmittingRoundings(const VoxelSet& a, const VoxelSet& b, Vec3 h,
                                         bool both_sides, const VoxelSet& got);

/// @brief The voxels of `box` inside one of the six closed tetrahedra
/// {0,1,3,7}, {0,1,5,7}, {0,2,3,7}, {0,2,6,7}, {0,4,5,7}, {0,4,6,7} of the
/// points img[0..7] (non-flat ones only), each tested by the signs of its
/// four orientation determinants computed from scratch.
VoxelSet BruteForceCubeImage(const Int3 (&img)[8], const VoxelBox& box, Int3 resolution);

/// A set holding exactly `voxels`.
VoxelSet VoxelSetOf(Int3 resolution, const std::vector<Int3>& voxels);

}  // namespace nimbus::testing
