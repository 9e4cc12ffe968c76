// Placeholder: only `linear` until the variations module lands.
#include "core/variations.h"

namespace nimbus {

Vec3 EvaluateVariation(const VariationTerm& v, Vec3 p, const Affine3&, Rng&) { return p; }

std::string_view VariationName(VariationKind) { return "linear"; }
std::optional<VariationKind> VariationFromName(std::string_view name) {
  if (name == "linear") return VariationKind::kLinear;
  return std::nullopt;
}
const std::vector<VariationKind>& AllVariations() {
  static const std::vector<VariationKind> all = {VariationKind::kLinear};
  return all;
}

}  // namespace nimbus
