#include "tests/support/volume_oracles.h"

#include <algorithm>
#include <cmath>
#include <set>
#include <tuple>

namespace nimbus::testing {

WorldSpread ActiveWorldSpread(const DenseVolume& v) {
  WorldSpread s;
  const Int3 r = v.frame.resolution;
  double weight = 0;
  Vec3 sum;
  for (int x = 0; x < r.x; ++x)
    for (int y = 0; y < r.y; ++y)
      for (int z = 0; z < r.z; ++z) {
        const float d = v.At(x, y, z);
        if (d == 0) continue;
        const Vec3 p = v.index_to_world.Apply({double(x), double(y), double(z)});
        for (int a = 0; a < 3; ++a) {
          s.box.min[a] = std::min(s.box.min[a], p[a]);
          s.box.max[a] = std::max(s.box.max[a], p[a]);
        }
        sum = sum + double(d) * p;
        weight += d;
        ++s.active;
      }
  if (weight > 0) s.centroid = (1.0 / weight) * sum;
  return s;
}

double Mass(const DenseVolume& v) {
  double sum = 0;
  for (float d : v.values) sum += d;
  return sum * std::abs(v.index_to_world.Determinant());
}

GridSupport CoarseSupport(const DenseVolume& v, int f) {
  std::set<std::tuple<int, int, int>> blocks, leaves;
  const Int3 r = v.frame.resolution;
  for (int x = 0; x < r.x; ++x)
    for (int y = 0; y < r.y; ++y)
      for (int z = 0; z < r.z; ++z)
        if (v.At(x, y, z) != 0) {
          blocks.emplace(x / f, y / f, z / f);
          leaves.emplace(x / f / 8, y / f / 8, z / f / 8);
        }
  return {blocks.size(), leaves.size()};
}

uint64_t CoarseActiveVoxels(const DenseVolume& v, int f) { return CoarseSupport(v, f).voxels; }

}  // namespace nimbus::testing
