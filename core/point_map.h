// Point maps and the point IFS they form.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "core/geometry.h"
#include "core/random.h"
#include "core/variations.h"

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
    return (static_cast<uint32_t>(r) < threshold_[i]) ? i : alias_[i];
  }
  size_t size() const { return n_; }

 private:
  uint64_t n_ = 0;
  std::vector<uint32_t> threshold_;  // scaled to 2^32
  std::vector<uint32_t> alias_;
};

/// @brief A point IFS with probabilities.
struct Ifs {
  std::vector<PointMap> maps;
  /// One per map, summing to 1.
  std::vector<double> probabilities;
  /// Optional final transform: applied to the plotted point only, outside the
  /// feedback loop (ALGORITHMS.md section 5).
  std::optional<PointMap> final_map;

  bool AllAffine() const;
};

/// Probabilities in proportion to |det A| of each map's pre-affine, each
/// raised to at least `floor` (relative to the largest) so that degenerate,
/// zero-volume maps are still picked. Returns normalised probabilities.
std::vector<double> DeterminantProbabilities(const std::vector<PointMap>& maps, double floor);

}  // namespace nimbus
