// AVX2 version of the affine walk: four lanes per register, four register
// groups per round. Compiled with -mavx2 only (no FMA), so every product and
// sum rounds exactly as in the scalar kernel. Includes nothing but the plain
// data header; see affine_walk.h.
#include <immintrin.h>

#include "core/chaos/affine_walk.h"
#include "core/chaos/xoshiro_avx2.h"

namespace nimbus::walk {

namespace {

// How a lane finds its map's table entries: with up to 4 (or 8) maps the
// tables sit in one (or two) registers and a lane permute fetches them;
// beyond that, gathers.
enum Lookup { kPermute4, kPermute8, kGather };

struct Tables {
  __m256i threshold8, alias8;        // up to 8 entries, uint32
  __m256d coef_lo[12], coef_hi[12];  // [j] = coefficient j of maps 0..3 / 4..7
};

inline __m256i Gather32(const uint32_t* table, __m256i index) {
  return _mm256_cvtepu32_epi64(
      _mm256_i64gather_epi32(reinterpret_cast<const int*>(table), index, 4));
}

inline __m256i Gather64(const uint64_t* table, __m256i index) {
  return _mm256_i64gather_epi64(reinterpret_cast<const long long*>(table), index, 8);
}

template <Lookup kLookup, bool kChain>
void Walk(const AffineWalk& k, Walkers& w, uint64_t steps) {
  alignas(32) Tables tab;
  if constexpr (kLookup != kGather) {
    if constexpr (!kChain) {  // a chain has its own tables, and no map alias table
      alignas(32) uint32_t thr[8] = {0}, ali[8] = {0};
      for (uint32_t m = 0; m < k.num_maps; ++m) thr[m] = k.threshold[m], ali[m] = k.alias[m];
      tab.threshold8 = _mm256_load_si256(reinterpret_cast<const __m256i*>(thr));
      tab.alias8 = _mm256_load_si256(reinterpret_cast<const __m256i*>(ali));
    }
    alignas(32) double lo[4], hi[4];
    for (int j = 0; j < 12; ++j) {
      for (uint32_t m = 0; m < 4; ++m) {
        lo[m] = m < k.num_maps ? k.coef[12 * m + j] : 0.0;
        hi[m] = m + 4 < k.num_maps ? k.coef[12 * (m + 4) + j] : 0.0;
      }
      tab.coef_lo[j] = _mm256_load_pd(lo);
      tab.coef_hi[j] = _mm256_load_pd(hi);
    }
  }
  const __m256i n = _mm256_set1_epi64x(k.num_maps);
  const __m256i low32 = _mm256_set1_epi64x(0xffffffffLL);
  const __m256i one = _mm256_set1_epi64x(1);
  const __m256d min_x = _mm256_set1_pd(k.min[0]), min_y = _mm256_set1_pd(k.min[1]),
                min_z = _mm256_set1_pd(k.min[2]);
  const __m256d inv_x = _mm256_set1_pd(k.inv_voxel[0]), inv_y = _mm256_set1_pd(k.inv_voxel[1]),
                inv_z = _mm256_set1_pd(k.inv_voxel[2]);
  const __m256d res_x = _mm256_set1_pd(k.res[0]), res_y = _mm256_set1_pd(k.res[1]),
                res_z = _mm256_set1_pd(k.res[2]);
  const __m256d zero = _mm256_setzero_pd();
  const __m128i tiles_y = _mm_set1_epi32(int(k.tiles_y)), tiles_z = _mm_set1_epi32(int(k.tiles_z));
  const __m128i three = _mm_set1_epi32(3), seven = _mm_set1_epi32(7);
  const __m128i in_bin = _mm_set1_epi32(int((1u << k.bin_shift) - 1));
  const __m128i bin_shift = _mm_cvtsi32_si128(int(k.bin_shift));
  const __m128i fold_mask = _mm_set1_epi32(int(k.fold_mask));
  const __m128i fold_shift = _mm_cvtsi32_si128(int(k.fold_shift));
  const __m128i flat_y = _mm_set1_epi32(int(k.flat_stride[0])),
                flat_z = _mm_set1_epi32(int(k.flat_stride[1]));

  for (uint64_t s = 0; s < steps; ++s) {
    for (int g = 0; g < kLanes; g += 4) {
      // xoshiro256++, four streams.
      __m256i s0 = _mm256_load_si256(reinterpret_cast<const __m256i*>(w.s0 + g));
      __m256i s1 = _mm256_load_si256(reinterpret_cast<const __m256i*>(w.s1 + g));
      __m256i s2 = _mm256_load_si256(reinterpret_cast<const __m256i*>(w.s2 + g));
      __m256i s3 = _mm256_load_si256(reinterpret_cast<const __m256i*>(w.s3 + g));
      const __m256i r = simd::XoshiroNext(s0, s1, s2, s3);
      _mm256_store_si256(reinterpret_cast<__m256i*>(w.s0 + g), s0);
      _mm256_store_si256(reinterpret_cast<__m256i*>(w.s1 + g), s1);
      _mm256_store_si256(reinterpret_cast<__m256i*>(w.s2 + g), s2);
      _mm256_store_si256(reinterpret_cast<__m256i*>(w.s3 + g), s3);

      // Alias sampling: i = (r_hi * n) >> 32, keep i if r_lo < threshold[i];
      // with a chain, over the transitions of the walker's state.
      __m256i m;
      __m256i plotted = _mm256_setzero_si256();  // bit 31 set: plot
      if constexpr (kChain) {
        const ChainTables& c = *k.chain;
        const __m256i st = _mm256_load_si256(reinterpret_cast<const __m256i*>(w.state + g));
        const __m256i info = Gather64(c.state, st);
        const __m256i off = _mm256_and_si256(info, low32);
        // mul_epu32 reads the low halves: r's high word times the count.
        const __m256i i = _mm256_srli_epi64(
            _mm256_mul_epu32(_mm256_srli_epi64(r, 32), _mm256_srli_epi64(info, 32)), 32);
        const __m256i sample = Gather64(c.sample, _mm256_add_epi64(off, i));
        const __m256i keep =
            _mm256_cmpgt_epi64(_mm256_and_si256(sample, low32), _mm256_and_si256(r, low32));
        const __m256i t =
            _mm256_add_epi64(off, _mm256_blendv_epi8(_mm256_srli_epi64(sample, 32), i, keep));
        const __m256i step = Gather64(c.step, t);
        m = _mm256_and_si256(step, _mm256_set1_epi64x(0x7fffffff));
        _mm256_store_si256(reinterpret_cast<__m256i*>(w.state + g), _mm256_srli_epi64(step, 32));
        plotted = step;
      } else {
        const __m256i i = _mm256_srli_epi64(_mm256_mul_epu32(_mm256_srli_epi64(r, 32), n), 32);
        __m256i thr, ali;
        if constexpr (kLookup == kGather) {
          thr = Gather32(k.threshold, i);
          ali = Gather32(k.alias, i);
        } else {
          thr = _mm256_and_si256(_mm256_permutevar8x32_epi32(tab.threshold8, i), low32);
          ali = _mm256_and_si256(_mm256_permutevar8x32_epi32(tab.alias8, i), low32);
        }
        const __m256i keep = _mm256_cmpgt_epi64(thr, _mm256_and_si256(r, low32));
        m = _mm256_blendv_epi8(ali, i, keep);
      }

      // The map's coefficients for each lane.
      __m256i pair, gather_index;
      __m256d hi_mask;
      if constexpr (kLookup == kGather) {
        gather_index = _mm256_add_epi64(_mm256_slli_epi64(m, 3), _mm256_slli_epi64(m, 2));
      } else {
        // Dwords 2m and 2m + 1 hold double m of a 4-double register; the
        // permute reads only 3 index bits, so maps 4..7 wrap onto the high
        // table and the blend on bit 2 of m picks it.
        const __m256i m2 = _mm256_slli_epi64(m, 1);
        pair = _mm256_or_si256(m2, _mm256_slli_epi64(_mm256_add_epi64(m2, one), 32));
        hi_mask = _mm256_castsi256_pd(_mm256_slli_epi64(m, 61));
      }
      auto coef = [&](int j) -> __m256d {
        if constexpr (kLookup == kGather) {
          return _mm256_i64gather_pd(k.coef + j, gather_index, 8);
        } else if constexpr (kLookup == kPermute4) {
          return _mm256_castsi256_pd(
              _mm256_permutevar8x32_epi32(_mm256_castpd_si256(tab.coef_lo[j]), pair));
        } else {
          const __m256d lo = _mm256_castsi256_pd(
              _mm256_permutevar8x32_epi32(_mm256_castpd_si256(tab.coef_lo[j]), pair));
          const __m256d hi = _mm256_castsi256_pd(
              _mm256_permutevar8x32_epi32(_mm256_castpd_si256(tab.coef_hi[j]), pair));
          return _mm256_blendv_pd(lo, hi, hi_mask);
        }
      };
      const __m256d x = _mm256_load_pd(w.x + g), y = _mm256_load_pd(w.y + g),
                    z = _mm256_load_pd(w.z + g);
      auto row = [&](int j) {
        __m256d v = _mm256_mul_pd(coef(j), x);
        v = _mm256_add_pd(v, _mm256_mul_pd(coef(j + 1), y));
        v = _mm256_add_pd(v, _mm256_mul_pd(coef(j + 2), z));
        return _mm256_add_pd(v, coef(j + 3));
      };
      const __m256d nx = row(0), ny = row(4), nz = row(8);
      _mm256_store_pd(w.x + g, nx);
      _mm256_store_pd(w.y + g, ny);
      _mm256_store_pd(w.z + g, nz);

      // Voxel coordinates and the inside test (NaN compares false).
      const __m256d fx = _mm256_mul_pd(_mm256_sub_pd(nx, min_x), inv_x);
      const __m256d fy = _mm256_mul_pd(_mm256_sub_pd(ny, min_y), inv_y);
      const __m256d fz = _mm256_mul_pd(_mm256_sub_pd(nz, min_z), inv_z);
      __m256d in =
          _mm256_and_pd(_mm256_cmp_pd(fx, zero, _CMP_GE_OQ), _mm256_cmp_pd(fx, res_x, _CMP_LT_OQ));
      in = _mm256_and_pd(in, _mm256_and_pd(_mm256_cmp_pd(fy, zero, _CMP_GE_OQ),
                                           _mm256_cmp_pd(fy, res_y, _CMP_LT_OQ)));
      in = _mm256_and_pd(in, _mm256_and_pd(_mm256_cmp_pd(fz, zero, _CMP_GE_OQ),
                                           _mm256_cmp_pd(fz, res_z, _CMP_LT_OQ)));
      const int inside = _mm256_movemask_pd(in);
      // Lanes in an unplotted chain state only need to be finite.
      const int plot =
          kChain ? _mm256_movemask_pd(_mm256_castsi256_pd(_mm256_slli_epi64(plotted, 32))) : 0xF;
      int finite = 0xF;
      if constexpr (kChain) {
        __m256d f = _mm256_cmp_pd(_mm256_sub_pd(nx, nx), zero, _CMP_EQ_OQ);
        f = _mm256_and_pd(f, _mm256_cmp_pd(_mm256_sub_pd(ny, ny), zero, _CMP_EQ_OQ));
        f = _mm256_and_pd(f, _mm256_cmp_pd(_mm256_sub_pd(nz, nz), zero, _CMP_EQ_OQ));
        finite = _mm256_movemask_pd(f);
      }

      const __m128i ix = _mm256_cvttpd_epi32(fx), iy0 = _mm256_cvttpd_epi32(fy),
                    iz0 = _mm256_cvttpd_epi32(fz);
      if (k.flat) {
        alignas(16) uint32_t index[4];
        const __m128i xy = _mm_add_epi32(_mm_mullo_epi32(ix, flat_y), iy0);
        _mm_store_si128(reinterpret_cast<__m128i*>(index),
                        _mm_add_epi32(_mm_mullo_epi32(xy, flat_z), iz0));
        AddFlatLanes(k, g, 4, plot, finite, inside, index);
        continue;
      }
      const __m128i iy = _mm_srl_epi32(iy0, fold_shift),
                    iz = _mm_add_epi32(iz0, _mm_and_si128(iy0, fold_mask));
      const __m128i tile = _mm_add_epi32(
          _mm_mullo_epi32(
              _mm_add_epi32(_mm_mullo_epi32(_mm_srli_epi32(ix, 5), tiles_y), _mm_srli_epi32(iy, 5)),
              tiles_z),
          _mm_srli_epi32(iz, 5));
      const __m128i leaf =
          _mm_or_si128(_mm_or_si128(_mm_slli_epi32(_mm_and_si128(_mm_srli_epi32(ix, 3), three), 4),
                                    _mm_slli_epi32(_mm_and_si128(_mm_srli_epi32(iy, 3), three), 2)),
                       _mm_and_si128(_mm_srli_epi32(iz, 3), three));
      const __m128i local =
          _mm_or_si128(_mm_slli_epi32(leaf, 9),
                       _mm_or_si128(_mm_or_si128(_mm_slli_epi32(_mm_and_si128(ix, seven), 6),
                                                 _mm_slli_epi32(_mm_and_si128(iy, seven), 3)),
                                    _mm_and_si128(iz, seven)));
      if (k.tiles) {
        alignas(16) uint32_t tiles[4], locals[4];
        _mm_store_si128(reinterpret_cast<__m128i*>(tiles), tile);
        _mm_store_si128(reinterpret_cast<__m128i*>(locals), local);
        AddLanes(k, g, 4, plot, finite, inside, tiles, locals);
        continue;
      }
      alignas(16) uint32_t bin[4], entry[4];
      _mm_store_si128(reinterpret_cast<__m128i*>(bin), _mm_srl_epi32(tile, bin_shift));
      _mm_store_si128(reinterpret_cast<__m128i*>(entry),
                      _mm_or_si128(_mm_slli_epi32(_mm_and_si128(tile, in_bin), 15), local));
      PushLanes(k, g, 4, plot, finite, inside, bin, entry);
    }
  }
}

template <bool kChain>
void WalkWith(const AffineWalk& k, Walkers& w, uint64_t steps) {
  if (k.num_maps <= 4)
    Walk<kPermute4, kChain>(k, w, steps);
  else if (k.num_maps <= 8)
    Walk<kPermute8, kChain>(k, w, steps);
  else
    Walk<kGather, kChain>(k, w, steps);
}

}  // namespace

void WalkAvx2(const AffineWalk& k, Walkers& w, uint64_t steps) {
  if (k.chain)
    WalkWith<true>(k, w, steps);
  else
    WalkWith<false>(k, w, steps);
}

}  // namespace nimbus::walk
