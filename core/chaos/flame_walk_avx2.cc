// The flame kernel with AVX2, four lanes per register, SLEEF's 3.5-ulp
// vector functions (1-ulp exp and pow, which come in no other). Compiled
// with -mavx2 and no FMA contraction, so the arithmetic around the
// elementary functions rounds exactly as the scalar kernel's.
#include <immintrin.h>
#include <sleef.h>

#include <cstdint>

// The vector types carry may_alias, which GCC drops (harmlessly) when they
// are template arguments.
#pragma GCC diagnostic ignored "-Wignored-attributes"
// GCC 12's gather intrinsics start from an undefined register, which it
// reports as uninitialised; every lane is written.
#pragma GCC diagnostic ignored "-Wuninitialized"
#ifndef __clang__  // a GCC-only warning (the fuzz build uses clang)
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#endif

namespace nimbus::formulas {
namespace {

inline __m256d Sqrt(__m256d a) { return _mm256_sqrt_pd(a); }  // correctly rounded
inline __m256d Sin(__m256d a) { return Sleef_sind4_u35avx2(a); }
inline __m256d Cos(__m256d a) { return Sleef_cosd4_u35avx2(a); }
inline void SinCos(__m256d a, __m256d* s, __m256d* c) {
  const auto both = Sleef_sincosd4_u35avx2(a);
  *s = both.x, *c = both.y;
}
inline __m256d Tan(__m256d a) { return Sleef_tand4_u35avx2(a); }
inline __m256d Atan2(__m256d y, __m256d x) { return Sleef_atan2d4_u35avx2(y, x); }
inline __m256d Exp(__m256d a) { return Sleef_expd4_u10avx2(a); }
inline __m256d Pow(__m256d a, __m256d b) { return Sleef_powd4_u10avx2(a, b); }
inline __m256d Cbrt(__m256d a) { return Sleef_cbrtd4_u35avx2(a); }
// Masks are all-ones lanes of a double vector.
inline __m256d IsNegative(__m256d a) { return _mm256_cmp_pd(a, _mm256_setzero_pd(), _CMP_LT_OQ); }
inline __m256d IsZero(__m256d a) { return _mm256_cmp_pd(a, _mm256_setzero_pd(), _CMP_EQ_OQ); }
inline __m256d IsPositive(__m256d a) { return _mm256_cmp_pd(a, _mm256_setzero_pd(), _CMP_GT_OQ); }
inline __m256d Select(__m256d m, __m256d a, __m256d b) { return _mm256_blendv_pd(b, a, m); }
inline bool AllZero(__m256d a) { return _mm256_movemask_pd(IsZero(a)) == 0xf; }

}  // namespace
}  // namespace nimbus::formulas

#include "core/chaos/flame_walk_kernel.h"
#include "core/chaos/xoshiro_avx2.h"

namespace nimbus::flame {
namespace {

struct Avx2Isa {
  using T = __m256d;
  static constexpr int kWidth = 4;
  static constexpr bool kStaged = false;  // no compress in AVX2
  static __m256d Load(const double* p) { return _mm256_load_pd(p); }
  static void Store(double* p, __m256d v) { _mm256_store_pd(p, v); }
  static __m128i Index(const int32_t* lanes) {
    return _mm_loadu_si128(reinterpret_cast<const __m128i*>(lanes));
  }
  static __m256d ToDouble(__m128i i) { return _mm256_cvtepi32_pd(i); }
  static void SortByMap(uint32_t maps, Walkers& w, int n) { SortByMapScalar(maps, w, n); }
  // AliasTable::Sample, four words at a time: the 32 x 32-bit product picks
  // the column, the low half of the word decides between it and its alias.
  static void PickMaps(const Program& p, Walkers& w, int n) {
    const __m256i num = _mm256_set1_epi64x(p.maps.num_maps);
    const __m256i low = _mm256_set1_epi64x(0xffffffff);
    const __m256i pack = _mm256_setr_epi32(0, 2, 4, 6, 1, 3, 5, 7);
    for (int k = 0; k < n; k += kWidth) {
      const __m256i r = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(w.words + k));
      const __m256i i = _mm256_srli_epi64(_mm256_mul_epu32(_mm256_srli_epi64(r, 32), num), 32);
      const __m256i threshold = _mm256_cvtepu32_epi64(
          _mm256_i64gather_epi32(reinterpret_cast<const int*>(p.threshold), i, 4));
      const __m256i alias = _mm256_cvtepu32_epi64(
          _mm256_i64gather_epi32(reinterpret_cast<const int*>(p.alias), i, 4));
      const __m256i keep = _mm256_cmpgt_epi64(threshold, _mm256_and_si256(r, low));
      const __m256i m = _mm256_blendv_epi8(alias, i, keep);
      _mm_storeu_si128(reinterpret_cast<__m128i*>(w.map + k),
                       _mm256_castsi256_si128(_mm256_permutevar8x32_epi32(m, pack)));
    }
  }
  static __m256d Gather(const double* base, __m128i i) { return _mm256_i32gather_pd(base, i, 8); }
  static __m256d LookupMaps(const double* table, uint32_t, __m128i i) { return Gather(table, i); }
  static void Scatter(double* base, __m128i i, __m256d v) {  // no scatter in AVX2
    alignas(32) double lane[4];
    alignas(16) int32_t at[4];
    _mm256_store_pd(lane, v);
    _mm_store_si128(reinterpret_cast<__m128i*>(at), i);
    for (int j = 0; j < 4; ++j) base[at[j]] = lane[j];
  }
  static __m256i GatherWord(const uint64_t* base, __m128i i) {
    return _mm256_i32gather_epi64(reinterpret_cast<const long long*>(base), i, 8);
  }
  static __m256i LoadWord(const uint64_t* p) {
    return _mm256_loadu_si256(reinterpret_cast<const __m256i*>(p));
  }
  // (w >> 11) 2^-53 exactly: both 32-bit halves convert exactly through the
  // 2^52 exponent trick and their sum stays below 2^53.
  static __m256d Uniform(__m256i w) {
    const __m256i v = _mm256_srli_epi64(w, 11);
    const __m256i magic = _mm256_set1_epi64x(0x4330000000000000);
    const __m256d two52 = _mm256_set1_pd(0x1.0p52);
    const __m256d hi = _mm256_sub_pd(
        _mm256_castsi256_pd(_mm256_or_si256(_mm256_srli_epi64(v, 32), magic)), two52);
    const __m256d lo = _mm256_sub_pd(
        _mm256_castsi256_pd(_mm256_or_si256(
            _mm256_and_si256(v, _mm256_set1_epi64x(0xffffffff)), magic)), two52);
    const __m256d whole = _mm256_add_pd(_mm256_mul_pd(hi, _mm256_set1_pd(0x1.0p32)), lo);
    return _mm256_mul_pd(whole, _mm256_set1_pd(0x1.0p-53));
  }
  static __m256d Bit(__m256i w) {
    return _mm256_castsi256_pd(_mm256_cmpgt_epi64(_mm256_setzero_si256(), w));
  }
  static __m256d Zero() { return _mm256_setzero_pd(); }
  // Rng::Next for four walkers per register.
  static void DrawWords(Walkers& w, int n, uint32_t words) {
    auto load = [](const uint64_t* p) {
      return _mm256_load_si256(reinterpret_cast<const __m256i*>(p));
    };
    auto store = [](uint64_t* p, __m256i v) {
      _mm256_store_si256(reinterpret_cast<__m256i*>(p), v);
    };
    for (int k = 0; k < n; k += kWidth) {
      __m256i s0 = load(w.s0 + k), s1 = load(w.s1 + k), s2 = load(w.s2 + k), s3 = load(w.s3 + k);
      for (uint32_t c = 0; c < words; ++c) {
        _mm256_storeu_si256(reinterpret_cast<__m256i*>(w.words + size_t(c) * kMaxWalkers + k),
                            simd::XoshiroNext(s0, s1, s2, s3));
      }
      store(w.s0 + k, s0), store(w.s1 + k, s1), store(w.s2 + k, s2), store(w.s3 + k, s3);
    }
  }
};

}  // namespace

void RoundAvx2(const Program& p, Walkers& w, int n) { RoundWith<Avx2Isa>(p, w, n); }

}  // namespace nimbus::flame
