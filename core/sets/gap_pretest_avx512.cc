// AVX-512 pretest: the moving voxels of a word are handled 16 at a time, in
// rank order (lane i is the word's moving voxel of rank r + i). Per-voxel
// bits of the neighbour words become lane masks with pext (bit j of
// pext(still, mov) is the bit of the j-th moving voxel), and the need mask
// goes back to x order with pdep. Integer work only, so the mask is exactly
// the portable one. Built with -mavx512f -mbmi -mbmi2 -mpopcnt; includes
// nothing but the plain data header (see gap_pretest.h).
#include <immintrin.h>

#include "core/sets/gap_pretest.h"

namespace nimbus::gap {
namespace {

// Positions of the set bits of `bits`, lowest first, into out[0..count);
// returns the count. `out` has room for 64 + 16 entries (16-lane stores).
inline int BitPositions(uint64_t bits, int32_t* out) {
  const __m512i iota = _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
  int count = 0;
  for (int c = 0; c < 4; ++c) {
    const __mmask16 m = __mmask16(bits >> (16 * c));
    if (!m) continue;
    const __m512i pos = _mm512_add_epi32(iota, _mm512_set1_epi32(16 * c));
    _mm512_storeu_si512(out + count, _mm512_maskz_compress_epi32(m, pos));
    count += __builtin_popcount(m);
  }
  return count;
}

// Lanes where v + bias, as unsigned, exceeds 2: v outside [-bias, 2 - bias].
inline __mmask16 Outside(__m512i v, int bias) {
  return _mm512_cmpgt_epu32_mask(_mm512_add_epi32(v, _mm512_set1_epi32(bias)),
                                 _mm512_set1_epi32(2));
}

// The images' three coordinates.
struct Coords {
  __m512i x, y, z;
};
// (The zero-masked shifts say the same as _mm512_srli_epi32, whose
// undefined pass-through GCC 12 reports as maybe uninitialised.)
inline Coords Unpack(__m512i p) {
  const __m512i ten = _mm512_set1_epi32(1023);
  return {_mm512_and_si512(p, ten),
          _mm512_and_si512(_mm512_maskz_srli_epi32(0xffff, p, 10), ten),
          _mm512_maskz_srli_epi32(0xffff, p, 20)};
}

// Lanes whose images q are two or more voxels from p (Chebyshev).
inline __mmask16 Apart(const Coords& p, __m512i q) {
  const Coords c = Unpack(q);
  return Outside(_mm512_sub_epi32(c.x, p.x), 1) | Outside(_mm512_sub_epi32(c.y, p.y), 1) |
         Outside(_mm512_sub_epi32(c.z, p.z), 1);
}

// Lanes `lanes` (of the moving voxels whose neighbour moves) read images
// images[pos[k + i]] for the i-th set lane: the neighbour's rank in its row.
inline __m512i GatherNeighbours(__mmask16 lanes, const int32_t* pos, int k,
                                const uint32_t* images) {
  const int n = __builtin_popcount(lanes);
  const __m512i packed = _mm512_maskz_loadu_epi32(__mmask16((1u << n) - 1), pos + k);
  const __m512i index = _mm512_maskz_expand_epi32(lanes, packed);
  return _mm512_mask_i32gather_epi32(_mm512_setzero_si512(), lanes, index, images, 4);
}

}  // namespace

uint64_t NeedAvx512(const Word& g) {
  const uint64_t mov = g.mov;
  alignas(64) int32_t xs[80], up[80], far[80];
  const int n = BitPositions(mov, xs);
  // Lane masks in rank order, and the neighbours' ranks: the j-th moving
  // voxel with a moving +y neighbour has the rank of the j-th set bit of
  // pext(mov, moves_y) in that row.
  uint64_t s[6];
  for (int k = 0; k < 6; ++k) s[k] = _pext_u64(g.still[k], mov);
  const uint64_t mx = _pext_u64(g.moves_x, mov), my = _pext_u64(g.moves_y, mov),
                 mz = _pext_u64(g.moves_z, mov);
  if (my) BitPositions(_pext_u64(mov, g.moves_y), up);
  if (mz) BitPositions(_pext_u64(mov, g.moves_z), far);
  uint64_t need = 0;
  int ky = 0, kz = 0;  // neighbour ranks used so far
  for (int r = 0; r < n; r += 16) {
    const __mmask16 lanes = __mmask16(n - r >= 16 ? 0xffffu : (1u << (n - r)) - 1);
    auto lane_bits = [&](uint64_t compact) { return __mmask16(compact >> r) & lanes; };
    const __m512i pm = _mm512_maskz_loadu_epi32(lanes, g.images + r);
    const Coords p = Unpack(pm);
    const __m512i x = _mm512_add_epi32(_mm512_maskz_load_epi32(lanes, xs + r), _mm512_set1_epi32(g.x0));
    const __m512i dx = _mm512_sub_epi32(p.x, x);
    const __m512i dy = _mm512_sub_epi32(p.y, _mm512_set1_epi32(g.y));
    const __m512i dz = _mm512_sub_epi32(p.z, _mm512_set1_epi32(g.z));
    const __mmask16 fx = Outside(dx, 1), fy = Outside(dy, 1), fz = Outside(dz, 1);
    // Neighbour a + e stays at a + e: the gap is max |d - e|; d - e within
    // [-1, 1] along e's axis means d in [-2, 0] (e = -1) or [0, 2] (e = +1).
    __mmask16 hit = (lane_bits(s[0]) & (Outside(dx, 2) | fy | fz)) |
                    (lane_bits(s[1]) & (Outside(dx, 0) | fy | fz)) |
                    (lane_bits(s[2]) & (Outside(dy, 2) | fx | fz)) |
                    (lane_bits(s[3]) & (Outside(dy, 0) | fx | fz)) |
                    (lane_bits(s[4]) & (Outside(dz, 2) | fx | fy)) |
                    (lane_bits(s[5]) & (Outside(dz, 0) | fx | fy));
    // Along x a moving neighbour is the next rank.
    const __mmask16 lx = lane_bits(mx);
    if (lx) hit |= lx & Apart(p, _mm512_maskz_loadu_epi32(lx, g.images + r + 1));
    const __mmask16 ly = lane_bits(my);
    if (ly) {
      hit |= ly & Apart(p, GatherNeighbours(ly, up, ky, g.images_y));
      ky += __builtin_popcount(ly);
    }
    const __mmask16 lz = lane_bits(mz);
    if (lz) {
      hit |= lz & Apart(p, GatherNeighbours(lz, far, kz, g.images_z));
      kz += __builtin_popcount(lz);
    }
    need |= uint64_t(hit) << r;
  }
  return _pdep_u64(need, mov);
}

}  // namespace nimbus::gap
