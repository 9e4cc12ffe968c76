// @brief Random IFS for the explorer (docs/explore.md): maps drawn from a
// seed, and the contraction measure that decides which IFS are kept.
#pragma once

#include <cstdint>
#include <vector>

#include "core/chaos/point_map.h"
#include "core/chaos/variation_kind.h"

namespace nimbus {

/// How an IFS's contraction is measured (docs/explore.md#the-contraction-test).
enum class ContractionMeasure {
  /// The largest singular value of any map's linear part.
  kSingularValue,
  /// The sum over the maps of |det A| (area or volume kept by one step).
  kDeterminant,
};

/// @brief What a random IFS is drawn from.
struct RandomIfsParams {
  /// 2: planar maps (z is halved, so the attractor lies in z = 0); 3: solid
  /// (then turned, see DrawRandomIfs).
  int dimensions = 2;
  int min_maps = 3, max_maps = 5;
  /// Entries of the linear part are uniform in [-coefficient_range, +...].
  double coefficient_range = 1;
  /// Translation components are uniform in [-translation_range, +...].
  double translation_range = 1;
  /// A map gets one of these (weight 1) with `variation_probability`.
  std::vector<VariationKind> variations;
  double variation_probability = 0.5;
};

/// The z scale of a planar map: contracting, so the attractor flattens to
/// z = 0, and |det| stays proportional to the planar |det| (the
/// determinant probabilities of the chaos game keep their ratios).
inline constexpr double kPlanarZScale = 0.5;

/// The turn given to solid IFS (25 degrees about x after -35 about y), so
/// that a picture looking down -z sees them from above and aside.
Affine3 SolidViewRotation();

/// Random IFS number `attempt` of `seed`: a pure function of (params, seed,
/// attempt), drawn from its own random stream. Solid IFS (3 dimensions) are
/// drawn, then conjugated by SolidViewRotation(): R A R^T and R b, the same
/// attractor turned, with the same singular values and determinants.
std::vector<PointMap> DrawRandomIfs(const RandomIfsParams& params, uint64_t seed,
                                    uint64_t attempt);

/// One map's share of the measure, on the linear part restricted to the
/// IFS's `dimensions` (the top-left 2x2 block for planar maps): its largest
/// singular value, or |det|.
double MapContraction(const Affine3& a, int dimensions, ContractionMeasure measure);

/// The IFS's contraction: the largest MapContraction (singular value) or
/// their sum (determinant), over the maps' affine parts (variations are not
/// measured).
double IfsContraction(const std::vector<PointMap>& maps, int dimensions,
                      ContractionMeasure measure);

}  // namespace nimbus
