// @brief Independent references for the jelly tests: per-voxel mean of
// leaf finite differences, and a brute-force VRR by address digits.
#pragma once

#include <cstdint>
#include <map>
#include <tuple>
#include <vector>

#include "core/base/geometry.h"

namespace nimbus::testing {

using VoxelKey = std::tuple<int, int, int>;

/// For each voxel of `frame` holding leaves, the mean of (leaf - prev) /
/// seconds over its leaves, computed leaf by leaf with a map.
std::map<VoxelKey, Vec3> MeanLeafVelocity(const std::vector<Vec3>& leaves,
                                          const std::vector<Vec3>& prev, double seconds,
                                          const GridFrame& frame);

/// VRR leaf `index` by its base-N digits: M_i1(M_i2(…M_iN(start))).
Vec3 VrrLeafByAddress(const std::vector<Affine3>& maps, uint32_t depth,
                      const std::vector<Vec3>& starts, uint64_t index);

}  // namespace nimbus::testing
