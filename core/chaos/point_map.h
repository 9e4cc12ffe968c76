// Point maps and the point IFS they form.
#pragma once

#include <cmath>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "core/base/geometry.h"
#include "core/base/random.h"
#include "core/chaos/variations.h"

namespace nimbus {

/// @brief One map of an IFS: p -> post( sum_i w_i V_i( pre(p) ) ).
/// With no variations the sum is the identity (pure affine map).
struct PointMap {
  std::string name;
  Affine3 pre;
  std::vector<VariationTerm> variations;
  std::optional<Affine3> post;
  /// Flame-style colour index in [0, 1] for colouring by map.
  double color = 0.0;

  bool IsAffine() const { return variations.empty() && !post.has_value(); }

  Vec3 Apply(Vec3 p, Rng& rng) const {
    Vec3 q = pre.Apply(p);
    if (!variations.empty()) {
      Vec3 sum;
      for (const VariationTerm& v : variations)
        sum = sum + v.weight * EvaluateVariation(v, q, pre, rng);
      q = sum;
    }
    return post ? post->Apply(q) : q;
  }
};

/// @brief Walker's alias table: O(1) sampling of a discrete distribution
/// from one 64-bit random word, reproducible across platforms.
class AliasTable {
 public:
  AliasTable() = default;
  /// `weights` must be non-negative with a positive sum.
  explicit AliasTable(const std::vector<double>& weights);
  uint32_t Sample(uint64_t r) const {
    const uint32_t i = static_cast<uint32_t>(((r >> 32) * n_) >> 32);
    // Branch-free select: with unequal weights the comparison is a coin
    // flip the branch predictor would miss half the time.
    const uint32_t keep = 0u - static_cast<uint32_t>(static_cast<uint32_t>(r) < threshold_[i]);
    return (i & keep) | (alias_[i] & ~keep);
  }
  size_t size() const { return n_; }
  /// The tables, for kernels that sample the same way (core/affine_walk.h).
  const uint32_t* thresholds() const { return threshold_.data(); }
  const uint32_t* aliases() const { return alias_.data(); }

 private:
  uint64_t n_ = 0;
  std::vector<uint32_t> threshold_;  // scaled to 2^32
  std::vector<uint32_t> alias_;
};

/// @brief The reference description's "arcs" final transform (docs/algorithms.md#final-transforms): a
/// rotation about the z axis by theta = angle_per_unit * x + amplitude *
/// sin(frequency * n), where x is the point's signed distance from the
/// x = 0 plane and n the index of the plotted step. The sinusoidal term
/// changes every step, which thickens the arcs that the x-proportional
/// rotation draws. Angles are in radians.
struct ArcsTransform {
  double angle_per_unit = 0;  // radians per world unit of x
  double amplitude = 0;       // radians
  double frequency = 0;       // radians per step

  Vec3 Apply(Vec3 p, uint64_t step) const {
    const double theta =
        angle_per_unit * p.x + amplitude * std::sin(frequency * static_cast<double>(step));
    const double c = std::cos(theta), s = std::sin(theta);
    return {c * p.x - s * p.y, s * p.x + c * p.y, p.z};
  }
};

/// @brief A point IFS with probabilities.
struct Ifs {
  std::vector<PointMap> maps;
  /// One per map, summing to 1.
  std::vector<double> probabilities;
  /// Optional final transform: applied to the plotted point only, outside the
  /// feedback loop (docs/algorithms.md#final-transforms).
  std::optional<PointMap> final_map;
  /// Optional arcs rotation, applied to the plotted point after final_map.
  std::optional<ArcsTransform> arcs;

  bool AllAffine() const;
};

/// Probabilities in proportion to |det A| of each map's pre-affine, each
/// raised to at least `floor` (relative to the largest) so that degenerate,
/// zero-volume maps are still picked. Returns normalised probabilities.
std::vector<double> DeterminantProbabilities(const std::vector<PointMap>& maps, double floor);

}  // namespace nimbus
