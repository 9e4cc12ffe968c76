// How a result's densities come from its counts (vdb_io.cc): the density
// mapping's name and the normaliser.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

#include "core/grid/count_grid.h"
#include "core/io/vdb_io.h"

namespace nimbus {

inline const char* MappingName(DensityMapping m) {
  switch (m) {
    case DensityMapping::kLinear:
      return "linear";
    case DensityMapping::kSqrt:
      return "sqrt";
    case DensityMapping::kLog:
      return "log";
    case DensityMapping::kGamma:
      return "gamma";
  }
  return "linear";
}

// Maps a count to [0, 1] given the largest count.
struct Normaliser {
  DensityMapping mapping;
  double max, inv_max, inv_log_max, inv_gamma;
  // Map(c) for the small counts that make up most voxels, where the
  // mapping calls the C library (log1p, sqrt, pow): a lookup, same floats.
  std::vector<float> small;
  Normaliser(const DensityOptions& o, uint32_t max_count)
      : mapping(o.mapping),
        max(std::max<double>(1, max_count)),
        inv_max(1.0 / max),
        inv_log_max(1.0 / std::log1p(max)),
        inv_gamma(1.0 / (o.gamma > 0 ? o.gamma : 1.0)) {
    constexpr uint32_t kSmall = 4096;
    if (mapping == DensityMapping::kLinear) return;
    small.resize(std::min(kSmall, max_count) + size_t{1});
    for (uint32_t c = 0; c < small.size(); ++c) small[c] = Map(c);
  }
  float operator()(uint32_t c) const { return c < small.size() ? small[c] : Map(c); }

 private:
  float Map(uint32_t c) const {
    switch (mapping) {
      case DensityMapping::kLinear:
        return float(c * inv_max);
      case DensityMapping::kSqrt:
        return float(std::sqrt(c * inv_max));
      case DensityMapping::kLog:
        return float(std::log1p(double(c)) * inv_log_max);
      case DensityMapping::kGamma:
        return float(std::pow(c * inv_max, inv_gamma));
    }
    return 0.f;
  }
};

}  // namespace nimbus
