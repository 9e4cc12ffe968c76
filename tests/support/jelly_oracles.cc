#include "tests/support/jelly_oracles.h"

#include <algorithm>
#include <cmath>

namespace nimbus::testing {

std::map<VoxelKey, Vec3> MeanLeafVelocity(const std::vector<Vec3>& leaves,
                                          const std::vector<Vec3>& prev, double seconds,
                                          const GridFrame& frame) {
  std::map<VoxelKey, std::pair<Vec3, int>> sums;
  const Vec3 h = frame.VoxelSize();
  for (size_t k = 0; k < leaves.size(); ++k) {
    const int x = int(std::floor((leaves[k].x - frame.bounds.min.x) / h.x));
    const int y = int(std::floor((leaves[k].y - frame.bounds.min.y) / h.y));
    const int z = int(std::floor((leaves[k].z - frame.bounds.min.z) / h.z));
    if (x < 0 || y < 0 || z < 0 || x >= frame.resolution.x || y >= frame.resolution.y ||
        z >= frame.resolution.z)
      continue;
    auto& [sum, n] = sums[{x, y, z}];
    sum = sum + (1.0 / seconds) * (leaves[k] - prev[k]);
    ++n;
  }
  std::map<VoxelKey, Vec3> out;
  for (const auto& [key, s] : sums) out[key] = (1.0 / s.second) * s.first;
  return out;
}

Vec3 VrrLeafByAddress(const std::vector<Affine3>& maps, uint32_t depth,
                      const std::vector<Vec3>& starts, uint64_t index) {
  Vec3 p = starts[index % starts.size()];
  uint64_t word = index / starts.size();
  // The last digit (least significant) acts first.
  for (uint32_t d = 0; d < depth; ++d) {
    p = maps[word % maps.size()].Apply(p);
    word /= maps.size();
  }
  return p;
}

double SymplecticFallHeight(double y0, double g, double dt, uint64_t n) {
  const double steps = double(n);
  return y0 - g * dt * dt * steps * (steps + 1) / 2;
}

uint64_t SymplecticLandingStep(double y0, double floor, double g, double dt) {
  // The largest n with y_n >= floor solves g·dt²·n(n+1)/2 = y0 - floor.
  const double drop = 2 * (y0 - floor) / (g * dt * dt);
  uint64_t n = uint64_t(std::max(0.0, std::floor((std::sqrt(1 + 4 * drop) - 1) / 2)));
  while (SymplecticFallHeight(y0, g, dt, n) >= floor) ++n;
  while (n > 1 && SymplecticFallHeight(y0, g, dt, n - 1) < floor) --n;
  return n;
}

}  // namespace nimbus::testing
