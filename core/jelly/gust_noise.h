// @brief Deterministic gusts: smooth value noise over space and time, a
// pure function of (seed, position, time), so a wind is the same on every
// run and thread.
#pragma once

#include <cstdint>

#include "core/base/geometry.h"

namespace nimbus {

/// Value noise in [-1, 1] per component at `p` (lattice units) and time `t`
/// (lattice units): hashed lattice values blended with a C1 smoothstep over
/// the 16 corners of the surrounding space-time cell.
Vec3 GustNoise(uint64_t seed, Vec3 p, double t);

}  // namespace nimbus
