// @brief RDN(i_1..i_n, k, S): the random value at a lattice node, a pure
// function of the node's integer coordinates, the mesh rank and the seed
// (docs/fractal_fields.md#node-values). Stateless, so any thread may compute
// any node in any order and get the same value.
#pragma once

#include <cstdint>

#include "core/base/random.h"

namespace nimbus {

/// @brief A node's coordinates by role: the spatial x, y, z and time t.
/// Axes a field does not have are 0; the time axis always takes the last
/// place, whatever the number of spatial axes.
struct NodeSlots {
  int64_t x = 0, y = 0, z = 0, t = 0;
};

/// The top 24 bits as a float in [-1, 1): k / 2^23 - 1, exact in float.
inline float HashToValue(uint64_t h) { return float(int32_t(h >> 40)) * 0x1p-23f - 1.0f; }

/// RDN: HashCoords(seed, mesh, x, y, z, t) mapped to [-1, 1) (uniform:
/// mean -2^-24, variance ~1/3).
inline float NodeValue(uint64_t seed, uint32_t mesh, const NodeSlots& n) {
  return HashToValue(HashCoords(seed, mesh, uint64_t(n.x), uint64_t(n.y), uint64_t(n.z),
                                uint64_t(n.t)));
}

/// HashCoords' state after the seed and the mesh: the grid evaluator
/// continues the chain one coordinate at a time (x per plane, y per row,
/// then z and t per node), which gives the same value as NodeValue.
inline uint64_t MeshPrefix(uint64_t seed, uint32_t mesh) { return Mix64(Mix64(seed) ^ mesh); }

}  // namespace nimbus
