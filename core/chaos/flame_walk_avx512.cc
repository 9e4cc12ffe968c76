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
// GCC 12's gather intrinsics start from an undefined register, which it
// reports as uninitialised; every lane is written.
#pragma GCC diagnostic ignored "-Wuninitialized"
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"

namespace nimbus::formulas {
namespace {

inline __m512d Sqrt(__m512d a) { return _mm512_sqrt_pd(a); }  // correctly rounded
inline __m512d Sin(__m512d a) { return Sleef_sind8_u10avx512f(a); }
inline __m512d Cos(__m512d a) { return Sleef_cosd8_u10avx512f(a); }
inline void SinCos(__m512d a, __m512d* s, __m512d* c) {
  const auto both = Sleef_sincosd8_u10avx512f(a);
  *s = both.x, *c = both.y;
}
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
#include "core/chaos/xoshiro_avx512.h"

namespace nimbus::flame {
namespace {

struct Avx512Isa {
  using T = __m512d;
  static constexpr int kWidth = 8;
  static __m512d Load(const double* p) { return _mm512_load_pd(p); }
  static void Store(double* p, __m512d v) { _mm512_store_pd(p, v); }
  static __m256i Index(const int32_t* lanes) {
    return _mm256_loadu_si256(reinterpret_cast<const __m256i*>(lanes));
  }
  static __m512d ToDouble(__m256i i) { return _mm512_cvtepi32_pd(i); }
  // AliasTable::Sample, eight words at a time: the 32 x 32-bit product picks
  // the column, the low half of the word decides between it and its alias.
  static void PickMaps(const Program& p, Walkers& w, int n) {
    const __m512i num = _mm512_set1_epi64(p.maps.num_maps);
    const __m512i low = _mm512_set1_epi64(0xffffffff);
    for (int k = 0; k < n; k += kWidth) {
      const __m512i r = _mm512_loadu_si512(w.words + k);
      const __m512i i = _mm512_srli_epi64(_mm512_mul_epu32(_mm512_srli_epi64(r, 32), num), 32);
      const __m512i threshold = _mm512_cvtepu32_epi64(_mm512_i64gather_epi32(i, p.threshold, 4));
      const __m512i alias = _mm512_cvtepu32_epi64(_mm512_i64gather_epi32(i, p.alias, 4));
      const __mmask8 keep = _mm512_cmplt_epu64_mask(_mm512_and_si512(r, low), threshold);
      _mm256_storeu_si256(reinterpret_cast<__m256i*>(w.map + k),
                          _mm512_cvtepi64_epi32(_mm512_mask_blend_epi64(keep, alias, i)));
    }
  }
  // With few maps, each map's walkers are compressed out of 16-lane
  // registers in walker order; else the counting sort.
  static void SortByMap(uint32_t maps, Walkers& w, int n) {
    if (maps > 8) return SortByMapScalar(maps, w, n);
    const __m512i iota = _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
    uint32_t at = 0;
    for (uint32_t m = 0; m < maps; ++m) {
      w.group[m] = at;
      const __m512i want = _mm512_set1_epi32(int(m));
      for (int k = 0; k < n; k += 16) {
        const __mmask16 is = n - k >= 16 ? _mm512_cmpeq_epi32_mask(
                                               _mm512_loadu_si512(w.map + k), want)
                                         : _mm512_mask_cmpeq_epi32_mask(
                                               __mmask16((1u << (n - k)) - 1),
                                               _mm512_loadu_si512(w.map + k), want);
        _mm512_mask_compressstoreu_epi32(w.order + at, is,
                                         _mm512_add_epi32(iota, _mm512_set1_epi32(k)));
        at += uint32_t(__builtin_popcount(is));
      }
    }
    w.group[maps] = at;
  }
  static __m512d Gather(const double* base, __m256i i) { return _mm512_i32gather_pd(i, base, 8); }
  static void Scatter(double* base, __m256i i, __m512d v) { _mm512_i32scatter_pd(base, i, v, 8); }
  static __m512i GatherWord(const uint64_t* base, __m256i i) {
    return _mm512_i32gather_epi64(i, base, 8);
  }
  // Exact: the 53 bits convert without rounding, as the scalar Rng's do.
  static __m512d Uniform(__m512i w) {
    return _mm512_mul_pd(_mm512_cvtepu64_pd(_mm512_srli_epi64(w, 11)), _mm512_set1_pd(0x1.0p-53));
  }
  static __mmask8 Bit(__m512i w) { return _mm512_movepi64_mask(w); }
  static __m512d Zero() { return _mm512_setzero_pd(); }
  // Rng::Next for eight walkers per register.
  static void DrawWords(Walkers& w, int n, uint32_t words) {
    for (int k = 0; k < n; k += kWidth) {
      __m512i s0 = _mm512_load_si512(w.s0 + k), s1 = _mm512_load_si512(w.s1 + k);
      __m512i s2 = _mm512_load_si512(w.s2 + k), s3 = _mm512_load_si512(w.s3 + k);
      for (uint32_t c = 0; c < words; ++c) {
        _mm512_storeu_si512(w.words + size_t(c) * kMaxWalkers + k,
                            simd::XoshiroNext(s0, s1, s2, s3));
      }
      _mm512_store_si512(w.s0 + k, s0), _mm512_store_si512(w.s1 + k, s1);
      _mm512_store_si512(w.s2 + k, s2), _mm512_store_si512(w.s3 + k, s3);
    }
  }
};

}  // namespace

void RoundAvx512(const Program& p, Walkers& w, int n) { RoundWith<Avx512Isa>(p, w, n); }

}  // namespace nimbus::flame
