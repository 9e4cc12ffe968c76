// AVX-512 version of the affine walk: eight lanes per register, two register
// groups per round. Compiled without FMA contraction, so every product and
// sum rounds exactly as in the scalar kernel and the counts are the same.
// Includes nothing but the plain data header (and the shared xoshiro
// step); see affine_walk.h.
#include <immintrin.h>

#include "core/chaos/affine_walk.h"
#include "core/chaos/xoshiro_avx512.h"

// GCC 12's AVX-512 headers start some intrinsics from an undefined register,
// which -Wmaybe-uninitialized reports; the values are all written.
#ifndef __clang__  // a GCC-only warning (the fuzz build uses clang)
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#endif

namespace nimbus::walk {

namespace {

// With up to 8 maps the tables sit in one register each and a lane permute
// fetches an entry; beyond that, gathers.
enum Lookup { kPermute, kGather };

struct Tables {
  __m512i threshold, alias;  // up to 8 entries, as uint64
  __m512d coef[12];          // [j] = coefficient j of maps 0..7
};

inline __m512i Gather32(const uint32_t* table, __m512i index) {
  return _mm512_cvtepu32_epi64(_mm512_i64gather_epi32(index, table, 4));
}

inline __m512i Gather64(const uint64_t* table, __m512i index) {
  return _mm512_i64gather_epi64(index, table, 8);
}

inline __m512i Load(const uint64_t* p) { return _mm512_load_si512(p); }
inline void Store(uint64_t* p, __m512i v) { _mm512_store_si512(p, v); }

// Direct mode's last stage for lanes [g, g + 8), of which `add` land in
// the grid (the walk has made the other lanes' exits): the tiles' pointers by one
// gather, the counters' addresses prefetched, and the increments deferred
// by one round (`pending`, applied here a round later and at the end of
// the walk): the counter's line then has a round's time to arrive, where
// an increment at once stalls the walk on its miss. Counts are sums, so
// their order is free. Lanes that add nothing increment `discard`.
inline void AddLanes8(const AffineWalk& k, int g, __mmask8 add, __m256i tile, __m256i local,
                      uint32_t** pending, uint32_t* discard) {
  const __m512i none = _mm512_setzero_si512();
  const auto* table = reinterpret_cast<const long long*>(k.tiles);
  __m512i ptr = _mm512_mask_i32gather_epi64(none, add, tile, table, 8);
  if (const __mmask8 missing = _mm512_mask_cmpeq_epi64_mask(add, ptr, none)) [[unlikely]] {
    alignas(32) uint32_t t[8];
    _mm256_store_si256(reinterpret_cast<__m256i*>(t), tile);
    for (unsigned m = missing; m; m &= m - 1) k.allocate(k.owner, t[__builtin_ctz(m)]);
    ptr = _mm512_mask_i32gather_epi64(none, add, tile, table, 8);
  }
  const __m512i addr = _mm512_mask_blend_epi64(
      add, _mm512_set1_epi64(reinterpret_cast<long long>(discard)),
      _mm512_add_epi64(ptr, _mm512_slli_epi64(_mm512_cvtepu32_epi64(local), 2)));
  alignas(64) uint32_t* a[8];
  _mm512_store_si512(a, addr);
  for (int l = 0; l < 8; ++l) _mm_prefetch(reinterpret_cast<const char*>(a[l]), _MM_HINT_T0);
  for (int l = 0; l < 8; ++l) ++*pending[g + l];
  _mm512_store_si512(pending + g, addr);
}

// Flat direct mode's last stage for lanes [g, g + 8), of which `add` land
// in the grid: `index` is each lane's lattice index into k.flat. The
// increments are deferred by a round (`pending`) as in AddLanes8, but not prefetched: a flat array small
// enough for this mode stays in L2, and the eight address extractions and
// prefetches cost more than they hide (bench/chaos_game_bench.cc,
// BM_Sierpinski2D).
inline void AddFlat8(const AffineWalk& k, uint32_t* flat, int g, __mmask8 add, __m256i index,
                     uint32_t* pending) {
  // A 512-bit blend: the 256-bit one needs AVX-512VL.
  index = _mm512_castsi512_si256(_mm512_mask_blend_epi32(
      add, _mm512_set1_epi32(int(k.flat_discard)), _mm512_castsi256_si512(index)));
  for (int l = 0; l < 8; ++l) ++flat[pending[g + l]];
  _mm256_store_si256(reinterpret_cast<__m256i*>(pending + g), index);
}

// kPlanar: the maps leave z out of x and y and set z to one constant
// (AffineWalk::planar), so z is neither computed nor stored and its voxel
// coordinate and inside test are the constant's. Up to the sign of a zero
// in x or y, which no voxel depends on, the walk is the general one.
// kSelfAlias: every map is its own alias (equal probabilities), so the
// sample is the drawn index whatever the threshold test says.
// kPixels: the walk is in voxel units already (min 0, inv_voxel 1 on x and
// y: a picture's pixels), and (x - 0) * 1 is x, bit for bit.
template <Lookup kLookup, bool kChain, bool kPlanar = false, bool kSelfAlias = false,
          bool kPixels = false>
void Walk(const AffineWalk& k, Walkers& w, uint64_t steps) {
  Tables tab;
  if constexpr (kLookup == kPermute) {
    alignas(64) uint64_t thr[8] = {0}, ali[8] = {0};
    if constexpr (!kChain) {  // a chain has its own tables, and no map alias table
      for (uint32_t m = 0; m < k.num_maps; ++m) thr[m] = k.threshold[m], ali[m] = k.alias[m];
    }
    tab.threshold = _mm512_load_si512(thr);
    tab.alias = _mm512_load_si512(ali);
    alignas(64) double c[8];
    for (int j = 0; j < 12; ++j) {
      for (uint32_t m = 0; m < 8; ++m) c[m] = m < k.num_maps ? k.coef[12 * m + j] : 0.0;
      tab.coef[j] = _mm512_load_pd(c);
    }
  }
  const __m512i n = _mm512_set1_epi64(k.num_maps);
  const __m512i low32 = _mm512_set1_epi64(0xffffffffLL);
  const __m512d min_x = _mm512_set1_pd(k.min[0]), min_y = _mm512_set1_pd(k.min[1]),
                min_z = _mm512_set1_pd(k.min[2]);
  const __m512d inv_x = _mm512_set1_pd(k.inv_voxel[0]), inv_y = _mm512_set1_pd(k.inv_voxel[1]),
                inv_z = _mm512_set1_pd(k.inv_voxel[2]);
  const __m512d res_x = _mm512_set1_pd(k.res[0]), res_y = _mm512_set1_pd(k.res[1]),
                res_z = _mm512_set1_pd(k.res[2]);
  const __m512d zero = _mm512_setzero_pd();
  const __m256i tiles_y = _mm256_set1_epi32(int(k.tiles_y)),
                tiles_z = _mm256_set1_epi32(int(k.tiles_z));
  const __m256i three = _mm256_set1_epi32(3), seven = _mm256_set1_epi32(7);
  const __m256i in_bin = _mm256_set1_epi32(int((1u << k.bin_shift) - 1));
  const __m128i bin_shift = _mm_cvtsi32_si128(int(k.bin_shift));
  const __m256i fold_mask = _mm256_set1_epi32(int(k.fold_mask));
  const __m128i fold_shift = _mm_cvtsi32_si128(int(k.fold_shift));
  const __m256i flat_y = _mm256_set1_epi32(int(k.flat_stride[0])),
                flat_z = _mm256_set1_epi32(int(k.flat_stride[1]));
  // Planar: z's voxel coordinate, computed as for any lane, and whether
  // it lies inside the grid (NaN fails).
  const double plane_fz = (k.coef[11] - k.min[2]) * k.inv_voxel[2];
  const __mmask8 plane_inside = plane_fz >= 0 && plane_fz < k.res[2] ? 0xFF : 0;
  const __m256i plane_iz = _mm256_set1_epi32(plane_inside ? int(plane_fz) : 0);

  uint32_t discard = 0;
  alignas(64) uint32_t* pending[kLanes];
  for (uint32_t*& p : pending) p = &discard;
  // In a local: a store through k.flat could otherwise alias k.
  uint32_t* const flat = k.flat;
  alignas(64) uint32_t pending_flat[kLanes];
  for (uint32_t& p : pending_flat) p = k.flat_discard;
  // The walkers live in registers, two groups of eight, and go through w
  // only around exits, which may restart walkers there: a load and a store
  // of six registers per group and step cost more than the step's own
  // arithmetic leaves room for.
  struct Group {
    __m512i s0, s1, s2, s3, state;
    __m512d x, y, z;
  } group[2];
  auto load = [&](Group& q, int g) {
    q.s0 = Load(w.s0 + g), q.s1 = Load(w.s1 + g), q.s2 = Load(w.s2 + g), q.s3 = Load(w.s3 + g);
    if constexpr (kChain) q.state = Load(w.state + g);
    q.x = _mm512_load_pd(w.x + g), q.y = _mm512_load_pd(w.y + g);
    if constexpr (!kPlanar) q.z = _mm512_load_pd(w.z + g);
  };
  auto store = [&](const Group& q, int g) {
    Store(w.s0 + g, q.s0), Store(w.s1 + g, q.s1), Store(w.s2 + g, q.s2), Store(w.s3 + g, q.s3);
    if constexpr (kChain) Store(w.state + g, q.state);
    _mm512_store_pd(w.x + g, q.x), _mm512_store_pd(w.y + g, q.y);
    if constexpr (!kPlanar) _mm512_store_pd(w.z + g, q.z);
  };
  load(group[0], 0);
  load(group[1], 8);
  for (uint64_t s = 0; s < steps; ++s) {
#pragma GCC unroll 2
    for (int h = 0; h < 2; ++h) {
      Group& q = group[h];
      const int g = 8 * h;
      // xoshiro256++, eight streams.
      const __m512i r = simd::XoshiroNext(q.s0, q.s1, q.s2, q.s3);

      // Alias sampling: i = (r_hi * n) >> 32, keep i if r_lo < threshold[i];
      // with a chain, over the transitions of the walker's state.
      __m512i m;
      __mmask8 plot = 0xFF;
      if constexpr (kChain) {
        const ChainTables& c = *k.chain;
        const __m512i info = Gather64(c.state, q.state);
        const __m512i off = _mm512_and_si512(info, low32);
        const __m512i i = _mm512_srli_epi64(
            _mm512_mul_epu32(_mm512_srli_epi64(r, 32), _mm512_srli_epi64(info, 32)), 32);
        const __m512i sample = Gather64(c.sample, _mm512_add_epi64(off, i));
        const __mmask8 keep =
            _mm512_cmpgt_epi64_mask(_mm512_and_si512(sample, low32), _mm512_and_si512(r, low32));
        const __m512i t2 =
            _mm512_add_epi64(off, _mm512_mask_blend_epi64(keep, _mm512_srli_epi64(sample, 32), i));
        const __m512i step = Gather64(c.step, t2);
        m = _mm512_and_si512(step, _mm512_set1_epi64(0x7fffffff));
        q.state = _mm512_srli_epi64(step, 32);
        plot = _mm512_test_epi64_mask(step, _mm512_set1_epi64(0x80000000LL));
      } else {
        const __m512i i = _mm512_srli_epi64(_mm512_mul_epu32(_mm512_srli_epi64(r, 32), n), 32);
        m = i;
        if constexpr (!kSelfAlias) {
          __m512i thr, ali;
          if constexpr (kLookup == kGather) {
            thr = Gather32(k.threshold, i);
            ali = Gather32(k.alias, i);
          } else {
            thr = _mm512_permutexvar_epi64(i, tab.threshold);
            ali = _mm512_permutexvar_epi64(i, tab.alias);
          }
          const __mmask8 keep = _mm512_cmpgt_epi64_mask(thr, _mm512_and_si512(r, low32));
          m = _mm512_mask_blend_epi64(keep, ali, i);
        }
      }

      // The map's coefficients for each lane.
      const __m512i gather_index = _mm512_mullo_epi64(m, _mm512_set1_epi64(12));
      auto coef = [&](int j) -> __m512d {
        if constexpr (kLookup == kGather)
          return _mm512_i64gather_pd(gather_index, k.coef + j, 8);
        else
          return _mm512_permutexvar_pd(m, tab.coef[j]);
      };
      const __m512d x = q.x, y = q.y, z = kPlanar ? zero : q.z;
      auto row = [&](int j) {
        __m512d v = _mm512_mul_pd(coef(j), x);
        v = _mm512_add_pd(v, _mm512_mul_pd(coef(j + 1), y));
        // Planar: z's term is a zero, which changes at most a zero's sign.
        if constexpr (!kPlanar) v = _mm512_add_pd(v, _mm512_mul_pd(coef(j + 2), z));
        return _mm512_add_pd(v, coef(j + 3));
      };
      const __m512d nx = row(0), ny = row(4), nz = kPlanar ? zero : row(8);
      q.x = nx, q.y = ny;
      if constexpr (!kPlanar) q.z = nz;

      // Voxel coordinates and the inside test (NaN compares false).
      const __m512d fx = kPixels ? nx : _mm512_mul_pd(_mm512_sub_pd(nx, min_x), inv_x);
      const __m512d fy = kPixels ? ny : _mm512_mul_pd(_mm512_sub_pd(ny, min_y), inv_y);
      const __m512d fz = _mm512_mul_pd(_mm512_sub_pd(nz, min_z), inv_z);
      __mmask8 inside =
          _mm512_cmp_pd_mask(fx, zero, _CMP_GE_OQ) & _mm512_cmp_pd_mask(fx, res_x, _CMP_LT_OQ) &
          _mm512_cmp_pd_mask(fy, zero, _CMP_GE_OQ) & _mm512_cmp_pd_mask(fy, res_y, _CMP_LT_OQ);
      if constexpr (kPlanar)
        inside &= plane_inside;
      else
        inside &= _mm512_cmp_pd_mask(fz, zero, _CMP_GE_OQ) &
                  _mm512_cmp_pd_mask(fz, res_z, _CMP_LT_OQ);
      // Lanes in an unplotted chain state only need to be finite.
      __mmask8 finite = 0xFF;
      if constexpr (kChain) {
        finite = _mm512_cmp_pd_mask(_mm512_sub_pd(nx, nx), zero, _CMP_EQ_OQ) &
                 _mm512_cmp_pd_mask(_mm512_sub_pd(ny, ny), zero, _CMP_EQ_OQ) &
                 _mm512_cmp_pd_mask(_mm512_sub_pd(nz, nz), zero, _CMP_EQ_OQ);
      }
      // Exits: lanes not plotted whose point is not finite, plotted ones
      // off the grid. The owner reads and may rewrite their lanes of w.
      const __mmask8 add = plot & inside;
      if (const __mmask8 out = (plot & ~inside) | (~plot & ~finite)) [[unlikely]] {
        store(q, g);
        for (unsigned e = out; e; e &= e - 1) k.exit(k.owner, g + __builtin_ctz(e));
        load(q, g);
      }

      const __m256i ix = _mm512_cvttpd_epi32(fx), iy0 = _mm512_cvttpd_epi32(fy),
                    iz0 = kPlanar ? plane_iz : _mm512_cvttpd_epi32(fz);
      if (k.flat) {
        const __m256i xy = _mm256_add_epi32(_mm256_mullo_epi32(ix, flat_y), iy0);
        AddFlat8(k, flat, g, add, _mm256_add_epi32(_mm256_mullo_epi32(xy, flat_z), iz0),
                 pending_flat);
        continue;
      }
      const __m256i iy = _mm256_srl_epi32(iy0, fold_shift),
                    iz = _mm256_add_epi32(iz0, _mm256_and_si256(iy0, fold_mask));
      const __m256i tile = _mm256_add_epi32(
          _mm256_mullo_epi32(_mm256_add_epi32(_mm256_mullo_epi32(_mm256_srli_epi32(ix, 5), tiles_y),
                                              _mm256_srli_epi32(iy, 5)),
                             tiles_z),
          _mm256_srli_epi32(iz, 5));
      const __m256i leaf = _mm256_or_si256(
          _mm256_or_si256(_mm256_slli_epi32(_mm256_and_si256(_mm256_srli_epi32(ix, 3), three), 4),
                          _mm256_slli_epi32(_mm256_and_si256(_mm256_srli_epi32(iy, 3), three), 2)),
          _mm256_and_si256(_mm256_srli_epi32(iz, 3), three));
      const __m256i local = _mm256_or_si256(
          _mm256_slli_epi32(leaf, 9),
          _mm256_or_si256(_mm256_or_si256(_mm256_slli_epi32(_mm256_and_si256(ix, seven), 6),
                                          _mm256_slli_epi32(_mm256_and_si256(iy, seven), 3)),
                          _mm256_and_si256(iz, seven)));
      if (k.tiles) {
        AddLanes8(k, g, add, tile, local, pending, &discard);
        continue;
      }
      alignas(32) uint32_t bin[8], entry[8];
      _mm256_store_si256(reinterpret_cast<__m256i*>(bin), _mm256_srl_epi32(tile, bin_shift));
      _mm256_store_si256(
          reinterpret_cast<__m256i*>(entry),
          _mm256_or_si256(_mm256_slli_epi32(_mm256_and_si256(tile, in_bin), 15), local));
      // Exits are made: only the lanes that land take part.
      PushLanes(k, g, 8, add, 0xFF, inside, bin, entry);
    }
  }
  store(group[0], 0);
  store(group[1], 8);
  for (uint32_t* p : pending) ++*p;  // the last round's increments
  if (k.flat)
    for (uint32_t p : pending_flat) ++k.flat[p];
}

// Whether every map is its own alias (Walk's kSelfAlias).
bool SelfAlias(const AffineWalk& k) {
  for (uint32_t m = 0; m < k.num_maps; ++m)
    if (k.alias[m] != m) return false;
  return true;
}

// Whether the walk's units are voxels on x and y (Walk's kPixels).
bool Pixels(const AffineWalk& k) {
  return k.min[0] == 0 && k.min[1] == 0 && k.inv_voxel[0] == 1 && k.inv_voxel[1] == 1;
}

// The planar walk's variants; chains never take it.
template <bool kSelfAlias>
void WalkPlanar(const AffineWalk& k, Walkers& w, uint64_t steps) {
  if (Pixels(k))
    Walk<kPermute, false, true, kSelfAlias, true>(k, w, steps);
  else
    Walk<kPermute, false, true, kSelfAlias>(k, w, steps);
}

template <bool kChain>
void WalkWith(const AffineWalk& k, Walkers& w, uint64_t steps) {
  const bool self_alias = !kChain && k.num_maps <= 8 && SelfAlias(k);
  if (!kChain && k.planar && k.num_maps <= 8)
    self_alias ? WalkPlanar<true>(k, w, steps) : WalkPlanar<false>(k, w, steps);
  else if (self_alias)
    Walk<kPermute, false, false, true>(k, w, steps);
  else if (k.num_maps <= 8)
    Walk<kPermute, kChain>(k, w, steps);
  else
    Walk<kGather, kChain>(k, w, steps);
}

}  // namespace

void WalkAvx512(const AffineWalk& k, Walkers& w, uint64_t steps) {
  if (k.chain)
    WalkWith<true>(k, w, steps);
  else
    WalkWith<false>(k, w, steps);
}

}  // namespace nimbus::walk
