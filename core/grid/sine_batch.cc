#include "core/grid/sine_batch.h"

#include <algorithm>
#include <cmath>

namespace nimbus {

void SinManyAt(SimdLevel level, const double* x, double* s, size_t n) {
  switch (std::min(level, DetectSimd())) {
    case SimdLevel::kAvx512:
      return sine_internal::SinAvx512(x, s, n);
    case SimdLevel::kAvx2:
      return sine_internal::SinAvx2(x, s, n);
    case SimdLevel::kScalar:
      break;
  }
  for (size_t k = 0; k < n; ++k) s[k] = std::sin(x[k]);
}

void SinMany(const double* x, double* s, size_t n) { SinManyAt(ActiveSimd(), x, s, n); }

}  // namespace nimbus
