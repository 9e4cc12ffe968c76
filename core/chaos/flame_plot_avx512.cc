// The plot kernel with AVX-512 (F and DQ), eight walkers per register
// (flame_plot_kernel.h). Compiled without FMA contraction.
#include <immintrin.h>

#include <cstdint>

// GCC 12's AVX-512 headers start some intrinsics from an undefined
// register, which it reports as uninitialised; every lane is written.
#ifndef __clang__  // a GCC-only warning (the fuzz build uses clang)
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#endif
#pragma GCC diagnostic ignored "-Wuninitialized"
// The vector types carry may_alias, which GCC drops (harmlessly) when they
// are template arguments.
#pragma GCC diagnostic ignored "-Wignored-attributes"

#include "core/chaos/flame_plot_kernel.h"

namespace nimbus::flame {
namespace {

struct Avx512PlotIsa {
  using D = __m512d;
  using I = __m512i;
  using M = __mmask8;
  static constexpr int kWidth = 8;
  static D Set(double v) { return _mm512_set1_pd(v); }
  static D Zero() { return _mm512_setzero_pd(); }
  static D Abs(D v) {
    return _mm512_castsi512_pd(
        _mm512_and_si512(_mm512_castpd_si512(v), _mm512_set1_epi64(0x7fffffffffffffff)));
  }
  static D Add(D a, D b) { return _mm512_add_pd(a, b); }
  static D Sub(D a, D b) { return _mm512_sub_pd(a, b); }
  static D Mul(D a, D b) { return _mm512_mul_pd(a, b); }
  static D Div(D a, D b) { return _mm512_div_pd(a, b); }
  static D Load(const double* p) { return _mm512_load_pd(p); }
  static M Ge(D a, D b) { return _mm512_cmp_pd_mask(a, b, _CMP_GE_OQ); }
  static M Lt(D a, D b) { return _mm512_cmp_pd_mask(a, b, _CMP_LT_OQ); }
  static M Gt(D a, D b) { return _mm512_cmp_pd_mask(a, b, _CMP_GT_OQ); }
  static M And(M a, M b) { return M(a & b); }
  static M All() { return 0xff; }
  static uint64_t Bits(M m) { return m; }
  static D Select(M m, D if_false, D if_true) { return _mm512_mask_blend_pd(m, if_false, if_true); }
  // Straight to 64-bit lanes (DQ's one-instruction conversion; the 32-bit
  // one narrows across lanes and costs three times as much): the same
  // integer wherever a key is kept, as kept coordinates and colours lie in
  // [0, 2^31). Elsewhere only the key's bits differ, and they are unused.
  static I TruncSigned(D v) { return _mm512_cvttpd_epi64(v); }
  static I TruncUnsigned(D v) { return _mm512_cvttpd_epi64(v); }
  static I Splat(uint64_t v) { return _mm512_set1_epi64(int64_t(v)); }
  static I AndI(I a, I b) { return _mm512_and_si512(a, b); }
  static I OrI(I a, I b) { return _mm512_or_si512(a, b); }
  static I AddI(I a, I b) { return _mm512_add_epi64(a, b); }
  static I MulLo32(I a, I b) { return _mm512_mul_epu32(a, b); }
  static I ShrBy(I a, uint32_t n) { return _mm512_srl_epi64(a, _mm_cvtsi32_si128(int(n))); }
  template <int k>
  static I Shl(I a) { return _mm512_slli_epi64(a, k); }
  template <int k>
  static I Shr(I a) { return _mm512_srli_epi64(a, k); }
  static void StoreKeys(uint64_t* p, I v) { _mm512_store_si512(p, v); }
};

}  // namespace

void PlotAvx512(const PlotTarget& t, const Walkers& w, bool final_map, int n, Plotted* out) {
  PlotKernel<Avx512PlotIsa>::Plot(t, w, final_map, n, out);
}

}  // namespace nimbus::flame
