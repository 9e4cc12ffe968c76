#include "core/chaos/point_map.h"

#include <algorithm>
#include <cmath>
#include <numeric>

namespace nimbus {

AliasTable::AliasTable(const std::vector<double>& weights)
    : n_(weights.size()), threshold_(weights.size()), alias_(weights.size()) {
  const double total = std::accumulate(weights.begin(), weights.end(), 0.0);
  std::vector<double> scaled(n_);
  std::vector<uint32_t> small, large;
  for (uint32_t i = 0; i < n_; ++i) {
    scaled[i] = weights[i] / total * static_cast<double>(n_);
    (scaled[i] < 1.0 ? small : large).push_back(i);
    alias_[i] = i;
  }
  while (!small.empty() && !large.empty()) {
    const uint32_t s = small.back(), l = large.back();
    small.pop_back();
    threshold_[s] = static_cast<uint32_t>(std::min(scaled[s] * 4294967296.0, 4294967295.0));
    alias_[s] = l;
    scaled[l] -= 1.0 - scaled[s];
    if (scaled[l] < 1.0) {
      large.pop_back();
      small.push_back(l);
    }
  }
  // Leftovers are 1 up to rounding: always keep themselves.
  for (uint32_t i : small) threshold_[i] = 0xffffffffu, alias_[i] = i;
  for (uint32_t i : large) threshold_[i] = 0xffffffffu, alias_[i] = i;
}

bool Ifs::AllAffine() const {
  return std::all_of(maps.begin(), maps.end(), [](const PointMap& m) { return m.IsAffine(); });
}

std::vector<double> DeterminantProbabilities(const std::vector<PointMap>& maps, double floor) {
  std::vector<double> p(maps.size());
  double largest = 0;
  for (size_t i = 0; i < maps.size(); ++i) {
    p[i] = std::fabs(maps[i].pre.Determinant());
    largest = std::max(largest, p[i]);
  }
  if (largest == 0) largest = 1;
  double total = 0;
  for (double& v : p) total += (v = std::max(v, floor * largest));
  if (total == 0) return std::vector<double>(maps.size(), 1.0 / maps.size());
  for (double& v : p) v /= total;
  return p;
}

}  // namespace nimbus
