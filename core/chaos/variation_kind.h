// @brief The variation kinds, alone: the SIMD flame kernels include this and
// nothing else of the engine (see variation_formulas.h).
#pragma once

namespace nimbus {

enum class VariationKind {
  kLinear,
  kSinusoidal,
  kSpherical,
  kSwirl,
  kHorseshoe,
  kPolar,
  kHandkerchief,
  kHeart,
  kDisc,
  kSpiral,
  kHyperbolic,
  kDiamond,
  kEx,
  kJulia,
  kBent,
  kWaves,
  kFisheye,
  kPopcorn,
  kExponential,
  kPower,
  kCylinder,
  kBubble,
  kBlur,
  kNoise,
  kPolarDoubling,  // the reference description's (r, theta) -> (r / sqrt 2, 2 theta)
};

}  // namespace nimbus
