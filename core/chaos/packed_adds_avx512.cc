// KeyBins' packed loops with AVX-512 F and DQ: the landed lanes compressed
// eight at a time, the adds' indices and amounts computed eight at a time,
// leaving two loads, one add to memory and the loop per key, where the
// scalar loops take about 29 instructions per key (a sixth of a flame
// job's CPU went to them).
#include <immintrin.h>

#include <bit>

#include "core/chaos/packed_adds.h"
#include "core/grid/count_grid.h"

// GCC 12's intrinsics start some results from an undefined register, which
// it reports as uninitialised; every lane is written.
#pragma GCC diagnostic ignored "-Wuninitialized"
#ifndef __clang__  // a GCC-only warning (the fuzz build uses clang)
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#endif

namespace nimbus::packed {

namespace {

uint32_t HoldAvx512(const uint64_t* words, const uint64_t* key, uint64_t lanes, uint64_t* hold) {
  uint32_t n = 0;
  // A compress into a register and a whole store: compressing straight to
  // memory is slow on some CPUs.
  for (int r = 0; r < 64; r += 8) {
    const __mmask8 m = __mmask8(lanes >> r);
    if (m == 0) continue;
    _mm512_storeu_si512(hold + n, _mm512_maskz_compress_epi64(m, _mm512_loadu_si512(key + r)));
    n += uint32_t(std::popcount(unsigned(m)));
  }
  for (uint32_t i = 0; i < n; ++i) __builtin_prefetch(words + (hold[i] & CountGrid::kVoxelMask), 1);
  return n;
}

uint64_t ApplyAvx512(uint64_t* words, const uint64_t* held, uint32_t n, bool weighted) {
  alignas(64) uint64_t at[kHoldRoom], add[kHoldRoom];
  const __m512i voxel = _mm512_set1_epi64(int64_t(CountGrid::kVoxelMask));
  const __m512i one = _mm512_set1_epi64(1);
  __m512i touched = _mm512_setzero_si512();
  for (uint32_t i = 0; i < n; i += 8) {
    const __mmask8 live = n - i >= 8 ? __mmask8(0xff) : __mmask8((1u << (n - i)) - 1);
    const __m512i k = _mm512_maskz_loadu_epi64(live, held + i);
    const __m512i v = _mm512_and_si512(k, voxel);
    const __m512i color = _mm512_srli_epi64(k, CountGrid::kColorShift);
    __m512i a;
    if (weighted) {
      const __m512i w = _mm512_add_epi64(
          _mm512_and_si512(_mm512_srli_epi64(k, CountGrid::kWeightShift), _mm512_set1_epi64(63)),
          one);
      a = _mm512_add_epi64(_mm512_slli_epi64(w, kCountShift), _mm512_mullo_epi64(w, color));
    } else {
      a = _mm512_add_epi64(_mm512_slli_epi64(one, kCountShift), color);
    }
    _mm512_store_si512(at + i, v);
    _mm512_store_si512(add + i, a);
    touched = _mm512_mask_or_epi64(touched, live, touched,
                                   _mm512_sllv_epi64(one, _mm512_srli_epi64(v, 15)));
  }
  for (uint32_t i = 0; i < n; ++i) words[at[i]] += add[i];
  return uint64_t(_mm512_reduce_or_epi64(touched));
}

constexpr Loops kAvx512{HoldAvx512, ApplyAvx512};

}  // namespace

const Loops& LoopsAvx512() { return kAvx512; }

}  // namespace nimbus::packed
