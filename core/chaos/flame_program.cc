#include "core/chaos/flame_program.h"

#include <algorithm>
#include <bit>

#include "core/chaos/variation_formulas.h"

namespace nimbus {

uint32_t FlameProgram::MapWords(const PointMap& map) {
  uint32_t n = 0;
  for (const VariationTerm& v : map.variations) n += uint32_t(formulas::VariationDraws(v.kind));
  return n;
}

bool FlameProgram::Planar(const PointMap& map) {
  const auto& a = map.pre.m;
  auto minus_zero = [](double v) {
    return std::bit_cast<uint64_t>(v) == std::bit_cast<uint64_t>(-0.0);
  };
  if (map.post || a[0][2] != 0 || a[1][2] != 0 || minus_zero(a[0][3]) || minus_zero(a[1][3]))
    return false;
  if (a[2][0] != 0 || a[2][1] != 0 || a[2][2] != 0 || std::bit_cast<uint64_t>(a[2][3]) != 0)
    return false;
  for (const VariationTerm& v : map.variations)
    if (v.kind == VariationKind::kBlur || v.kind == VariationKind::kNoise) return false;
  return true;
}

void FlameProgram::Tables::Add(const PointMap& map) {
  if (first_term.empty()) first_term.push_back(0);
  for (const auto& row : map.pre.m) pre.insert(pre.end(), row.begin(), row.end());
  const Affine3 after = map.post.value_or(Affine3::Identity());
  for (const auto& row : after.m) post.insert(post.end(), row.begin(), row.end());
  has_post.push_back(map.post.has_value());
  has_terms.push_back(!map.variations.empty());
  color.push_back(map.color);
  words.push_back(MapWords(map));
  uint32_t draw = 0;
  for (const VariationTerm& v : map.variations) {
    terms.push_back({uint32_t(v.kind), v.weight, draw});
    draw += uint32_t(formulas::VariationDraws(v.kind));
  }
  first_term.push_back(uint32_t(terms.size()));
}

flame::MapTables FlameProgram::Tables::View() const {
  return {pre.data(),   post.data(),  has_post.data(),        has_terms.data(), first_term.data(),
          terms.data(), color.data(), uint32_t(color.size()), words.data()};
}

FlameProgram::FlameProgram(const std::vector<PointMap>& maps,
                           const std::optional<PointMap>& final_map, const AliasTable& table,
                           int color_mode, double blend) {
  uint32_t map_words = 0;
  bool planar = !final_map;
  for (const PointMap& m : maps) {
    maps_.Add(m);
    map_words = std::max(map_words, MapWords(m));
    planar = planar && Planar(m);
  }
  if (final_map) final_.Add(*final_map);
  view_.maps = maps_.View();
  view_.final_map = final_.View();
  view_.threshold = table.thresholds();
  view_.alias = table.aliases();
  view_.final_word = 1 + map_words;
  view_.words = view_.final_word + (final_map ? MapWords(*final_map) : 0);
  view_.color_mode = color_mode;
  view_.blend = blend;
  view_.inv_maps = 1.0 / double(maps.size());
  view_.planar = planar;
}

flame::RoundFn FlameKernel(SimdLevel level) {
  switch (std::min(level, DetectSimd())) {
    case SimdLevel::kAvx512:
      return &flame::RoundAvx512;
    case SimdLevel::kAvx2:
      return &flame::RoundAvx2;
    case SimdLevel::kScalar:
      break;
  }
  return &flame::RoundScalar;
}

flame::PlotFn FlamePlotter(SimdLevel level) {
  switch (std::min(level, DetectSimd())) {
    case SimdLevel::kAvx512:
      return &flame::PlotAvx512;
    case SimdLevel::kAvx2:
      return &flame::PlotAvx2;
    case SimdLevel::kScalar:
      break;
  }
  return &flame::PlotScalar;
}

}  // namespace nimbus
