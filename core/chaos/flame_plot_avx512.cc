// The plot kernel with AVX-512 (F and DQ), eight walkers per register.
// Compiled without FMA contraction: every operation is one correctly
// rounded add, multiply or divide in the scalar kernel's order, so the keys
// are the scalar kernel's bit for bit.
#include <immintrin.h>

#include <cstdint>

#include "core/chaos/flame_plot.h"

// GCC 12's AVX-512 headers start some intrinsics from an undefined
// register, which it reports as uninitialised; every lane is written.
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#pragma GCC diagnostic ignored "-Wuninitialized"

namespace nimbus::flame {
namespace {

using D = __m512d;
using I = __m512i;

D Set(double v) { return _mm512_set1_pd(v); }
D Add(D a, D b) { return _mm512_add_pd(a, b); }
D Sub(D a, D b) { return _mm512_sub_pd(a, b); }
D Mul(D a, D b) { return _mm512_mul_pd(a, b); }

// |v| < inf: false for infinities and NaN, as std::isfinite.
__mmask8 Finite(D v) {
  const D abs = _mm512_castsi512_pd(
      _mm512_and_si512(_mm512_castpd_si512(v), _mm512_set1_epi64(0x7fffffffffffffff)));
  return _mm512_cmp_pd_mask(abs, Set(__builtin_inf()), _CMP_LT_OQ);
}
// lo <= v < hi, false for NaN.
__mmask8 InRange(D v, double lo, double hi) {
  return _mm512_cmp_pd_mask(v, Set(lo), _CMP_GE_OQ) & _mm512_cmp_pd_mask(v, Set(hi), _CMP_LT_OQ);
}
// One row of view * q in Affine3::Apply's order.
D Row(const double* r, D x, D y, D z) {
  return Add(Add(Add(Mul(Set(r[0]), x), Mul(Set(r[1]), y)), Mul(Set(r[2]), z)), Set(r[3]));
}

// The lattice coordinates of eight points and the lanes that land.
__mmask8 Project(const PlotTarget& t, D x, D y, D z, D f[3]) {
  __mmask8 in = 0xff;
  if (t.kind == PlotTarget::kGrid) {
    f[0] = Mul(Sub(x, Set(t.min[0])), Set(t.inv_voxel[0]));
    f[1] = Mul(Sub(y, Set(t.min[1])), Set(t.inv_voxel[1]));
    f[2] = Mul(Sub(z, Set(t.min[2])), Set(t.inv_voxel[2]));
  } else {
    D cx = Row(t.view, x, y, z), cy = Row(t.view + 4, x, y, z);
    const D cz = Row(t.view + 8, x, y, z);
    if (t.kind == PlotTarget::kPerspective) {
      in = _mm512_cmp_pd_mask(cz, Set(t.near), _CMP_GT_OQ);
      cx = Add(Set(t.cx), _mm512_div_pd(Mul(Set(t.focal), cx), cz));
      cy = Sub(Set(t.cy), _mm512_div_pd(Mul(Set(t.focal), cy), cz));
    } else {
      in = InRange(cz, 0, 1);
    }
    f[0] = cx, f[1] = cy, f[2] = _mm512_setzero_pd();
  }
  return in & InRange(f[0], 0, t.res[0]) & InRange(f[1], 0, t.res[1]) &
         InRange(f[2], 0, t.res[2]);
}

// CountGrid::Key of the truncated coordinates, in 64-bit lanes.
I Key(const PlotTarget& t, const D f[3]) {
  const I x = _mm512_cvtepi32_epi64(_mm512_cvttpd_epi32(f[0]));
  const I y = _mm512_cvtepi32_epi64(_mm512_cvttpd_epi32(f[1]));
  const I z = _mm512_cvtepi32_epi64(_mm512_cvttpd_epi32(f[2]));
  const I sy = _mm512_srl_epi64(y, _mm_cvtsi32_si128(int(t.fold_shift)));
  const I sz = _mm512_add_epi64(z, _mm512_and_si512(y, _mm512_set1_epi64(t.fold_mask)));
  auto tile_of = [](I v) { return _mm512_srli_epi64(v, 5); };
  I tile = _mm512_add_epi64(_mm512_mul_epu32(tile_of(x), _mm512_set1_epi64(t.tiles_y)),
                            tile_of(sy));
  tile = _mm512_add_epi64(_mm512_mul_epu32(tile, _mm512_set1_epi64(t.tiles_z)), tile_of(sz));
  // LocalOffset: leaf (lx >> 3, ly >> 3, lz >> 3) at bits 13, 11, 9, then
  // (lx & 7, ly & 7, lz & 7) at bits 6, 3, 0.
  const I hi3 = _mm512_set1_epi64(0x18), lo3 = _mm512_set1_epi64(7);
  I off = _mm512_slli_epi64(_mm512_and_si512(x, hi3), 10);
  off = _mm512_or_si512(off, _mm512_slli_epi64(_mm512_and_si512(sy, hi3), 8));
  off = _mm512_or_si512(off, _mm512_slli_epi64(_mm512_and_si512(sz, hi3), 6));
  off = _mm512_or_si512(off, _mm512_slli_epi64(_mm512_and_si512(x, lo3), 6));
  off = _mm512_or_si512(off, _mm512_slli_epi64(_mm512_and_si512(sy, lo3), 3));
  off = _mm512_or_si512(off, _mm512_and_si512(sz, lo3));
  return _mm512_or_si512(_mm512_slli_epi64(tile, 15), off);
}

// ColorBits: clamp to [0, 1], c * 65535 + 0.5 truncated, at bit 48.
I ColorBits(D col) {
  D c = _mm512_mask_blend_pd(_mm512_cmp_pd_mask(col, Set(0), _CMP_LT_OQ), col, Set(0));
  c = _mm512_mask_blend_pd(_mm512_cmp_pd_mask(Set(1), c, _CMP_LT_OQ), c, Set(1));
  const __m256i c16 = _mm512_cvttpd_epi32(Add(Mul(c, Set(65535.0)), Set(0.5)));
  return _mm512_slli_epi64(_mm512_cvtepu32_epi64(c16), 48);
}

}  // namespace

void PlotAvx512(const PlotTarget& t, const Walkers& w, bool final_map, int n, Plotted* out) {
  const double* px = final_map ? w.fx : w.x;
  const double* py = final_map ? w.fy : w.y;
  const double* pz = final_map ? w.fz : w.z;
  uint64_t inside = 0, bad_walker = 0, bad_final = 0;
  for (int k = 0; k < n; k += 8) {
    const __mmask8 walker = Finite(_mm512_load_pd(w.x + k)) & Finite(_mm512_load_pd(w.y + k)) &
                            Finite(_mm512_load_pd(w.z + k));
    const D x = _mm512_load_pd(px + k), y = _mm512_load_pd(py + k), z = _mm512_load_pd(pz + k);
    const __mmask8 point = walker & Finite(x) & Finite(y) & Finite(z);
    D f[3];
    const __mmask8 in = point & Project(t, x, y, z, f);
    I key = Key(t, f);
    if (t.color) key = _mm512_or_si512(key, ColorBits(_mm512_load_pd(w.col + k)));
    _mm512_store_si512(out->key + k, key);
    inside |= uint64_t(in) << k;
    bad_walker |= uint64_t(uint8_t(~walker)) << k;
    bad_final |= uint64_t(uint8_t(walker & ~point)) << k;
  }
  out->inside = inside, out->bad_walker = bad_walker, out->bad_final = bad_final;
}

}  // namespace nimbus::flame
