// Reference attractors shared by the chaos-game benchmark and tests, so the
// figures and the checks run on exactly the IFS of the examples.
#pragma once

#include <cstdint>

#include "core/chaos/chaos_game.h"

namespace nimbus {

/// The four half-size maps onto the corners of a regular tetrahedron in
/// [-1, 1]^3 (examples/sierpinski_tetrahedron.json, determinant weights).
ChaosGameParams SierpinskiTetrahedronParams(int resolution, uint64_t iterations);

/// A volume-filling cloud: eight half-size copies at the octants of
/// [-1, 1]^3, each turned a little about (1, 1, 1); equal probabilities.
ChaosGameParams OctantCloudParams(int resolution, uint64_t iterations);

/// The IFS of examples/fern_volume.json: a 3D fern whose maps' volume
/// factors sum above 1, so its attractor fills volume; determinant
/// weights with floor 0.01, bounds [-5.4, 5.4] x [-0.2, 10.6] x [-5.4, 5.4].
ChaosGameParams FernVolumeParams(int resolution, uint64_t iterations);

}  // namespace nimbus
