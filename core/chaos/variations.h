// Nonlinear "variations" (flame-style) in true 3D form. Each map of an IFS is
// an affine pre-transform, a weighted sum of variations, then an optional
// post-affine (see point_map.h). docs/variations.md gives every formula.
#pragma once

#include <array>
#include <cstdint>
#include <optional>
#include <string_view>
#include <vector>

#include "core/base/geometry.h"
#include "core/base/random.h"
#include "core/chaos/variation_kind.h"

namespace nimbus {

/// One weighted term of a map's variation sum. `params` carries the few
/// variations that take parameters; unused entries are ignored.
struct VariationTerm {
  VariationKind kind = VariationKind::kLinear;
  double weight = 1.0;
  std::array<double, 4> params{};
};

/// Evaluates variation `v.kind` (unweighted) at `p`, the pre-transformed
/// point. `pre` is the map's pre-affine, whose coefficients the dependent
/// variations (waves, popcorn, ...) read. Random variations draw from `rng`.
/// May return non-finite values; callers detect and re-seed.
Vec3 EvaluateVariation(const VariationTerm& v, Vec3 p, const Affine3& pre, Rng& rng);
/// The same with the random words pre-drawn: `words` holds VariationWords
/// of them, read in the order the Rng version draws (a uniform is word >>
/// 11 times 2^-53, a bit the top bit of a word).
Vec3 EvaluateVariation(const VariationTerm& v, Vec3 p, const Affine3& pre,
                       const uint64_t* words);
/// Random words one evaluation of `kind` takes (0 for most).
int VariationWords(VariationKind kind);

/// Canonical lower-case name ("sinusoidal", "polar_doubling", ...).
std::string_view VariationName(VariationKind kind);
std::optional<VariationKind> VariationFromName(std::string_view name);
/// Every kind, in enum order.
const std::vector<VariationKind>& AllVariations();

/// Static facts about one variation, for validators, explorers and UIs.
struct VariationInfo {
  std::string_view name;   // same as VariationName
  int param_count = 0;     // leading entries of VariationTerm::params it reads
  bool planar = false;     // classic 2D formula in the xy plane (docs: z rule)
  bool random = false;     // draws from the Rng
  bool reads_pre = false;  // reads coefficients of the pre-affine
};
const VariationInfo& GetVariationInfo(VariationKind kind);

}  // namespace nimbus
