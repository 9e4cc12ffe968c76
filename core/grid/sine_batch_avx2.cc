// SinMany with AVX2: four lanes per call of SLEEF's 1-ulp sin, the tail
// through a zero-padded copy.
#include <immintrin.h>
#include <sleef.h>

#include "core/grid/sine_batch.h"

namespace nimbus::sine_internal {

void SinAvx2(const double* x, double* s, size_t n) {
  size_t k = 0;
  for (; k + 4 <= n; k += 4) _mm256_storeu_pd(s + k, Sleef_sind4_u10avx2(_mm256_loadu_pd(x + k)));
  if (k == n) return;
  alignas(32) double in[4] = {0, 0, 0, 0}, out[4];
  for (size_t i = k; i < n; ++i) in[i - k] = x[i];
  _mm256_store_pd(out, Sleef_sind4_u10avx2(_mm256_load_pd(in)));
  for (size_t i = k; i < n; ++i) s[i] = out[i - k];
}

}  // namespace nimbus::sine_internal
