// The plot kernel with AVX2, four walkers per register. Compiled without
// FMA contraction: every operation is one correctly rounded add, multiply
// or divide in the scalar kernel's order, so the keys are the scalar
// kernel's bit for bit.
#include <immintrin.h>

#include <cstdint>

#include "core/chaos/flame_plot.h"

namespace nimbus::flame {
namespace {

using D = __m256d;
using I = __m256i;

D Set(double v) { return _mm256_set1_pd(v); }
D Add(D a, D b) { return _mm256_add_pd(a, b); }
D Sub(D a, D b) { return _mm256_sub_pd(a, b); }
D Mul(D a, D b) { return _mm256_mul_pd(a, b); }
D And(D a, D b) { return _mm256_and_pd(a, b); }

// Masks are all-ones lanes. |v| < inf: false for infinities and NaN.
D Finite(D v) {
  const D abs = _mm256_andnot_pd(Set(-0.0), v);
  return _mm256_cmp_pd(abs, Set(__builtin_inf()), _CMP_LT_OQ);
}
// lo <= v < hi, false for NaN.
D InRange(D v, double lo, double hi) {
  return And(_mm256_cmp_pd(v, Set(lo), _CMP_GE_OQ), _mm256_cmp_pd(v, Set(hi), _CMP_LT_OQ));
}
// One row of view * q in Affine3::Apply's order.
D Row(const double* r, D x, D y, D z) {
  return Add(Add(Add(Mul(Set(r[0]), x), Mul(Set(r[1]), y)), Mul(Set(r[2]), z)), Set(r[3]));
}

// The lattice coordinates of four points and the lanes that land.
D Project(const PlotTarget& t, D x, D y, D z, D f[3]) {
  D in = _mm256_castsi256_pd(_mm256_set1_epi64x(-1));
  if (t.kind == PlotTarget::kGrid) {
    f[0] = Mul(Sub(x, Set(t.min[0])), Set(t.inv_voxel[0]));
    f[1] = Mul(Sub(y, Set(t.min[1])), Set(t.inv_voxel[1]));
    f[2] = Mul(Sub(z, Set(t.min[2])), Set(t.inv_voxel[2]));
  } else {
    D cx = Row(t.view, x, y, z), cy = Row(t.view + 4, x, y, z);
    const D cz = Row(t.view + 8, x, y, z);
    if (t.kind == PlotTarget::kPerspective) {
      in = _mm256_cmp_pd(cz, Set(t.near), _CMP_GT_OQ);
      cx = Add(Set(t.cx), _mm256_div_pd(Mul(Set(t.focal), cx), cz));
      cy = Sub(Set(t.cy), _mm256_div_pd(Mul(Set(t.focal), cy), cz));
    } else {
      in = InRange(cz, 0, 1);
    }
    f[0] = cx, f[1] = cy, f[2] = _mm256_setzero_pd();
  }
  return And(And(in, InRange(f[0], 0, t.res[0])),
             And(InRange(f[1], 0, t.res[1]), InRange(f[2], 0, t.res[2])));
}

// CountGrid::Key of the truncated coordinates, in 64-bit lanes.
I Key(const PlotTarget& t, const D f[3]) {
  const I x = _mm256_cvtepi32_epi64(_mm256_cvttpd_epi32(f[0]));
  const I y = _mm256_cvtepi32_epi64(_mm256_cvttpd_epi32(f[1]));
  const I z = _mm256_cvtepi32_epi64(_mm256_cvttpd_epi32(f[2]));
  const I sy = _mm256_srl_epi64(y, _mm_cvtsi32_si128(int(t.fold_shift)));
  const I sz = _mm256_add_epi64(z, _mm256_and_si256(y, _mm256_set1_epi64x(t.fold_mask)));
  auto tile_of = [](I v) { return _mm256_srli_epi64(v, 5); };
  I tile = _mm256_add_epi64(_mm256_mul_epu32(tile_of(x), _mm256_set1_epi64x(t.tiles_y)),
                            tile_of(sy));
  tile = _mm256_add_epi64(_mm256_mul_epu32(tile, _mm256_set1_epi64x(t.tiles_z)), tile_of(sz));
  // LocalOffset: leaf (lx >> 3, ly >> 3, lz >> 3) at bits 13, 11, 9, then
  // (lx & 7, ly & 7, lz & 7) at bits 6, 3, 0.
  const I hi3 = _mm256_set1_epi64x(0x18), lo3 = _mm256_set1_epi64x(7);
  I off = _mm256_slli_epi64(_mm256_and_si256(x, hi3), 10);
  off = _mm256_or_si256(off, _mm256_slli_epi64(_mm256_and_si256(sy, hi3), 8));
  off = _mm256_or_si256(off, _mm256_slli_epi64(_mm256_and_si256(sz, hi3), 6));
  off = _mm256_or_si256(off, _mm256_slli_epi64(_mm256_and_si256(x, lo3), 6));
  off = _mm256_or_si256(off, _mm256_slli_epi64(_mm256_and_si256(sy, lo3), 3));
  off = _mm256_or_si256(off, _mm256_and_si256(sz, lo3));
  return _mm256_or_si256(_mm256_slli_epi64(tile, 15), off);
}

// ColorBits: clamp to [0, 1], c * 65535 + 0.5 truncated, at bit 48.
I ColorBits(D col) {
  D c = _mm256_blendv_pd(col, Set(0), _mm256_cmp_pd(col, Set(0), _CMP_LT_OQ));
  c = _mm256_blendv_pd(c, Set(1), _mm256_cmp_pd(Set(1), c, _CMP_LT_OQ));
  const __m128i c16 = _mm256_cvttpd_epi32(Add(Mul(c, Set(65535.0)), Set(0.5)));
  return _mm256_slli_epi64(_mm256_cvtepu32_epi64(c16), 48);
}

uint64_t Bits(D mask) { return uint64_t(_mm256_movemask_pd(mask)); }

}  // namespace

void PlotAvx2(const PlotTarget& t, const Walkers& w, bool final_map, int n, Plotted* out) {
  const double* px = final_map ? w.fx : w.x;
  const double* py = final_map ? w.fy : w.y;
  const double* pz = final_map ? w.fz : w.z;
  uint64_t inside = 0, bad_walker = 0, bad_final = 0;
  for (int k = 0; k < n; k += 4) {
    const D walker = And(And(Finite(_mm256_load_pd(w.x + k)), Finite(_mm256_load_pd(w.y + k))),
                         Finite(_mm256_load_pd(w.z + k)));
    const D x = _mm256_load_pd(px + k), y = _mm256_load_pd(py + k), z = _mm256_load_pd(pz + k);
    const D point = And(walker, And(And(Finite(x), Finite(y)), Finite(z)));
    D f[3];
    const D in = And(point, Project(t, x, y, z, f));
    I key = Key(t, f);
    if (t.color) key = _mm256_or_si256(key, ColorBits(_mm256_load_pd(w.col + k)));
    _mm256_store_si256(reinterpret_cast<I*>(out->key + k), key);
    inside |= Bits(in) << k;
    bad_walker |= (Bits(walker) ^ 0xf) << k;
    bad_final |= (Bits(walker) & ~Bits(point)) << k;
  }
  out->inside = inside, out->bad_walker = bad_walker, out->bad_final = bad_final;
}

}  // namespace nimbus::flame
