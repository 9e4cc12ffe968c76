// @brief Independent references for the jelly tests: per-voxel mean of
// leaf finite differences, a brute-force VRR by address digits, and the
// closed form of a free fall under symplectic Euler.
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

/// Height after `n` symplectic Euler steps of `dt` of a body released at
/// rest from `y0` under gravity -g: v_k = -g·k·dt, so
/// y_n = y0 - g·dt²·n(n+1)/2.
double SymplecticFallHeight(double y0, double g, double dt, uint64_t n);

/// The first step n whose fall height is below `floor` (where a ground at
/// `floor` first catches the body).
uint64_t SymplecticLandingStep(double y0, double floor, double g, double dt);

}  // namespace nimbus::testing
