// The plot kernel with AVX2, four walkers per register
// (flame_plot_kernel.h). Compiled without FMA contraction.
#include <immintrin.h>

#include <cstdint>

// The vector types carry may_alias, which GCC drops (harmlessly) when they
// are template arguments.
#pragma GCC diagnostic ignored "-Wignored-attributes"

#include "core/chaos/flame_plot_kernel.h"

namespace nimbus::flame {
namespace {

// Masks are all-ones lanes of doubles.
struct Avx2PlotIsa {
  using D = __m256d;
  using I = __m256i;
  using M = __m256d;
  static constexpr int kWidth = 4;
  static D Set(double v) { return _mm256_set1_pd(v); }
  static D Zero() { return _mm256_setzero_pd(); }
  static D Abs(D v) { return _mm256_andnot_pd(Set(-0.0), v); }
  static D Add(D a, D b) { return _mm256_add_pd(a, b); }
  static D Sub(D a, D b) { return _mm256_sub_pd(a, b); }
  static D Mul(D a, D b) { return _mm256_mul_pd(a, b); }
  static D Div(D a, D b) { return _mm256_div_pd(a, b); }
  static D Load(const double* p) { return _mm256_load_pd(p); }
  static M Ge(D a, D b) { return _mm256_cmp_pd(a, b, _CMP_GE_OQ); }
  static M Lt(D a, D b) { return _mm256_cmp_pd(a, b, _CMP_LT_OQ); }
  static M Gt(D a, D b) { return _mm256_cmp_pd(a, b, _CMP_GT_OQ); }
  static M And(M a, M b) { return _mm256_and_pd(a, b); }
  static M All() { return _mm256_castsi256_pd(_mm256_set1_epi64x(-1)); }
  static uint64_t Bits(M m) { return uint64_t(_mm256_movemask_pd(m)); }
  static D Select(M m, D if_false, D if_true) { return _mm256_blendv_pd(if_false, if_true, m); }
  static I TruncSigned(D v) { return _mm256_cvtepi32_epi64(_mm256_cvttpd_epi32(v)); }
  static I TruncUnsigned(D v) { return _mm256_cvtepu32_epi64(_mm256_cvttpd_epi32(v)); }
  static I Splat(uint64_t v) { return _mm256_set1_epi64x(int64_t(v)); }
  static I AndI(I a, I b) { return _mm256_and_si256(a, b); }
  static I OrI(I a, I b) { return _mm256_or_si256(a, b); }
  static I AddI(I a, I b) { return _mm256_add_epi64(a, b); }
  static I MulLo32(I a, I b) { return _mm256_mul_epu32(a, b); }
  static I ShrBy(I a, uint32_t n) { return _mm256_srl_epi64(a, _mm_cvtsi32_si128(int(n))); }
  template <int k>
  static I Shl(I a) { return _mm256_slli_epi64(a, k); }
  template <int k>
  static I Shr(I a) { return _mm256_srli_epi64(a, k); }
  static void StoreKeys(uint64_t* p, I v) { _mm256_store_si256(reinterpret_cast<I*>(p), v); }
};

}  // namespace

void PlotAvx2(const PlotTarget& t, const Walkers& w, bool final_map, int n, Plotted* out) {
  PlotKernel<Avx2PlotIsa>::Plot(t, w, final_map, n, out);
}

}  // namespace nimbus::flame
