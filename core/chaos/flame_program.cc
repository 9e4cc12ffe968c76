#include "core/chaos/flame_program.h"

#include <algorithm>

#include "core/chaos/variation_formulas.h"

namespace nimbus {
namespace {

void AppendAffine(const Affine3& a, std::vector<double>& out) {
  for (const auto& row : a.m) out.insert(out.end(), row.begin(), row.end());
}

// A flag in the first of a map's 12 entries (flame_walk.h).
void AppendFlag(bool flag, std::vector<double>& out) {
  out.push_back(flag ? 1.0 : 0.0);
  out.insert(out.end(), 11, 0.0);
}

}  // namespace

FlameProgram::FlameProgram(const std::vector<PointMap>& maps) {
  random_.resize(maps.size());
  for (uint32_t m = 0; m < maps.size(); ++m) {
    const PointMap& map = maps[m];
    AppendAffine(map.pre, pre_);
    AppendAffine(map.post.value_or(Affine3::Identity()), post_);
    AppendFlag(map.post.has_value(), has_post_);
    AppendFlag(!map.variations.empty(), has_terms_);
    uint32_t column = 0;
    for (const VariationTerm& v : map.variations) {
      terms_.push_back({m, uint32_t(v.kind), v.weight, column});
      const int n = formulas::VariationDraws(v.kind);
      if (n > 0) random_[m].push_back(v.kind);
      column += uint32_t(n);
    }
    columns_ = std::max(columns_, column);
  }
  view_ = {pre_.data(),       post_.data(),  has_post_.data(),
           has_terms_.data(), terms_.data(), uint32_t(terms_.size())};
}

void FlameProgram::Draw(uint32_t map, Rng& rng, double* draws, int slot) const {
  double* out = draws + slot;
  for (VariationKind kind : random_[map]) {
    if (kind == VariationKind::kJulia) {
      *out = double(rng.Next() >> 63);
      out += flame::kSlots;
      continue;
    }
    for (int i = 0; i < formulas::VariationDraws(kind); ++i, out += flame::kSlots)
      *out = rng.Uniform();
  }
}

flame::ApplyMapsFn FlameKernel(SimdLevel level) {
  switch (std::min(level, DetectSimd())) {
    case SimdLevel::kAvx512:
      return &flame::ApplyMapsAvx512;
    case SimdLevel::kAvx2:
      return &flame::ApplyMapsAvx2;
    case SimdLevel::kScalar:
      break;
  }
  return &flame::ApplyMapsScalar;
}

}  // namespace nimbus
