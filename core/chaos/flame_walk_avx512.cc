// The flame kernel with AVX-512, eight lanes per register, SLEEF's 1-ulp
// vector functions. Compiled without FMA contraction, so the arithmetic
// around the elementary functions rounds exactly as the scalar kernel's.
#include <immintrin.h>
#include <sleef.h>

#include <cstdint>

// GCC 12's AVX-512 headers start some intrinsics from an undefined register,
// which -Wmaybe-uninitialized reports; the values are all written.
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"

// The vector types carry may_alias, which GCC drops (harmlessly) when they
// are template arguments.
#pragma GCC diagnostic ignored "-Wignored-attributes"

namespace nimbus::formulas {
namespace {

inline __m512d Sqrt(__m512d a) { return _mm512_sqrt_pd(a); }  // correctly rounded
inline __m512d Sin(__m512d a) { return Sleef_sind8_u10avx512f(a); }
inline __m512d Cos(__m512d a) { return Sleef_cosd8_u10avx512f(a); }
inline __m512d Tan(__m512d a) { return Sleef_tand8_u10avx512f(a); }
inline __m512d Atan2(__m512d y, __m512d x) { return Sleef_atan2d8_u10avx512f(y, x); }
inline __m512d Exp(__m512d a) { return Sleef_expd8_u10avx512f(a); }
inline __m512d Pow(__m512d a, __m512d b) { return Sleef_powd8_u10avx512f(a, b); }
inline __m512d Cbrt(__m512d a) { return Sleef_cbrtd8_u10avx512f(a); }
inline __mmask8 IsNegative(__m512d a) {
  return _mm512_cmp_pd_mask(a, _mm512_setzero_pd(), _CMP_LT_OQ);
}
inline __mmask8 IsZero(__m512d a) { return _mm512_cmp_pd_mask(a, _mm512_setzero_pd(), _CMP_EQ_OQ); }
inline __mmask8 IsPositive(__m512d a) {
  return _mm512_cmp_pd_mask(a, _mm512_setzero_pd(), _CMP_GT_OQ);
}
inline __m512d Select(__mmask8 m, __m512d a, __m512d b) { return _mm512_mask_blend_pd(m, b, a); }

}  // namespace
}  // namespace nimbus::formulas

#include "core/chaos/flame_walk_kernel.h"

namespace nimbus::flame {
namespace {

struct Avx512Isa {
  using T = __m512d;
  static constexpr int kWidth = 8;
  static __m512d Load(const double* p) { return _mm512_loadu_pd(p); }
  static void Store(double* p, __m512d v) { _mm512_storeu_pd(p, v); }
  static __m512i Index(const int64_t* map) {
    return _mm512_mullo_epi64(_mm512_loadu_si512(map), _mm512_set1_epi64(12));
  }
  static __m512d Gather(const double* table, __m512i index, int j) {
    return _mm512_i64gather_pd(index, table + j, 8);
  }
  static __m512d Zero() { return _mm512_setzero_pd(); }
  static __mmask8 MapIs(const int64_t* map, uint32_t m) {
    return _mm512_cmpeq_epi64_mask(_mm512_loadu_si512(map), _mm512_set1_epi64(m));
  }
  static bool Any(__mmask8 mask) { return mask != 0; }
};

}  // namespace

void ApplyMapsAvx512(const MapTables& t, Batch& b) { ApplyMapsWith<Avx512Isa>(t, b); }

}  // namespace nimbus::flame
