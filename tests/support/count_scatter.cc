#include "tests/support/count_scatter.h"

#include <random>

namespace nimbus::testing {

CountGrid ScatterColorCounts(Int3 r, int n, uint32_t seed) {
  CountGrid counts(r, /*with_color=*/true);
  std::mt19937 rng(seed);
  for (int k = 0; k < n; ++k) {
    const int x = int(rng() % uint32_t(r.x)), y = int(rng() % uint32_t(r.y)),
              z = int(rng() % uint32_t(r.z));
    const uint32_t times = k % 7 == 0 ? 1 + rng() % 40 : 1;
    for (uint32_t t = 0; t < times; ++t)
      counts.AddKey(CountGrid::WithColor(counts.Key(x, y, z), rng() % CountGrid::kColorScale));
  }
  return counts;
}

}  // namespace nimbus::testing
