// The flame kernel with AVX2, four lanes per register, SLEEF's 1-ulp vector
// functions. Compiled with -mavx2 and no FMA contraction, so the arithmetic
// around the elementary functions rounds exactly as the scalar kernel's.
#include <immintrin.h>
#include <sleef.h>

#include <cstdint>

// The vector types carry may_alias, which GCC drops (harmlessly) when they
// are template arguments.
#pragma GCC diagnostic ignored "-Wignored-attributes"

namespace nimbus::formulas {
namespace {

inline __m256d Sqrt(__m256d a) { return _mm256_sqrt_pd(a); }  // correctly rounded
inline __m256d Sin(__m256d a) { return Sleef_sind4_u10avx2(a); }
inline __m256d Cos(__m256d a) { return Sleef_cosd4_u10avx2(a); }
inline __m256d Tan(__m256d a) { return Sleef_tand4_u10avx2(a); }
inline __m256d Atan2(__m256d y, __m256d x) { return Sleef_atan2d4_u10avx2(y, x); }
inline __m256d Exp(__m256d a) { return Sleef_expd4_u10avx2(a); }
inline __m256d Pow(__m256d a, __m256d b) { return Sleef_powd4_u10avx2(a, b); }
inline __m256d Cbrt(__m256d a) { return Sleef_cbrtd4_u10avx2(a); }
// Masks are all-ones lanes of a double vector.
inline __m256d IsNegative(__m256d a) { return _mm256_cmp_pd(a, _mm256_setzero_pd(), _CMP_LT_OQ); }
inline __m256d IsZero(__m256d a) { return _mm256_cmp_pd(a, _mm256_setzero_pd(), _CMP_EQ_OQ); }
inline __m256d IsPositive(__m256d a) { return _mm256_cmp_pd(a, _mm256_setzero_pd(), _CMP_GT_OQ); }
inline __m256d Select(__m256d m, __m256d a, __m256d b) { return _mm256_blendv_pd(b, a, m); }

}  // namespace
}  // namespace nimbus::formulas

#include "core/chaos/flame_walk_kernel.h"

namespace nimbus::flame {
namespace {

struct Avx2Isa {
  using T = __m256d;
  static constexpr int kWidth = 4;
  static __m256d Load(const double* p) { return _mm256_loadu_pd(p); }
  static void Store(double* p, __m256d v) { _mm256_storeu_pd(p, v); }
  static __m256i Index(const int64_t* map) {
    const __m256i m = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(map));
    return _mm256_add_epi64(_mm256_slli_epi64(m, 3), _mm256_slli_epi64(m, 2));  // 12 m
  }
  static __m256d Gather(const double* table, __m256i index, int j) {
    return _mm256_i64gather_pd(table + j, index, 8);
  }
  static __m256d Zero() { return _mm256_setzero_pd(); }
  static __m256d MapIs(const int64_t* map, uint32_t m) {
    const __m256i v = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(map));
    return _mm256_castsi256_pd(_mm256_cmpeq_epi64(v, _mm256_set1_epi64x(m)));
  }
  static bool Any(__m256d mask) { return _mm256_movemask_pd(mask) != 0; }
};

}  // namespace

void ApplyMapsAvx2(const MapTables& t, Batch& b) { ApplyMapsWith<Avx2Isa>(t, b); }

}  // namespace nimbus::flame
