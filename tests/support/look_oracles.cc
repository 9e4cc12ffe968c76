#include "tests/support/look_oracles.h"

#include <cstddef>

namespace nimbus::testing {

std::vector<double> BoxCascadeKernel(const std::vector<int>& widths) {
  std::vector<double> k{1.0};
  for (int w : widths) {
    std::vector<double> next(k.size() + size_t(w) - 1, 0.0);
    for (size_t i = 0; i < k.size(); ++i)
      for (int j = 0; j < w; ++j) next[i + size_t(j)] += k[i] / w;
    k = std::move(next);
  }
  return k;
}

double LitFraction(const RgbImage& image, Vec3 background) {
  size_t lit = 0;
  const size_t n = size_t(image.width) * size_t(image.height);
  for (size_t p = 0; p < n; ++p) {
    const float* c = &image.rgb[3 * p];
    lit += c[0] != float(background.x) || c[1] != float(background.y) ||
           c[2] != float(background.z);
  }
  return n ? double(lit) / double(n) : 0;
}

}  // namespace nimbus::testing
