// SinMany with AVX-512: eight lanes per call of SLEEF's 1-ulp sin, the
// tail through a masked load and store.
#include <immintrin.h>
#include <sleef.h>

#include "core/grid/sine_batch.h"

namespace nimbus::sine_internal {

void SinAvx512(const double* x, double* s, size_t n) {
  size_t k = 0;
  for (; k + 8 <= n; k += 8) _mm512_storeu_pd(s + k, Sleef_sind8_u10avx512f(_mm512_loadu_pd(x + k)));
  if (k == n) return;
  const __mmask8 tail = __mmask8((1u << (n - k)) - 1);
  const __m512d v = Sleef_sind8_u10avx512f(_mm512_maskz_loadu_pd(tail, x + k));
  _mm512_mask_storeu_pd(s + k, tail, v);
}

}  // namespace nimbus::sine_internal
