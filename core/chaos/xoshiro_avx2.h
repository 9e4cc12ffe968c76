// @brief xoshiro256++ (core/base/random.h's Rng::Next) on four streams at
// once, one per 64-bit lane, for the AVX2 kernels. Include only from
// translation units compiled for AVX2.
#pragma once

#include <immintrin.h>

namespace nimbus::simd {

/// The four streams' next outputs; advances the state (s0..s3 hold lane
/// l's words s[0..3]).
inline __m256i XoshiroNext(__m256i& s0, __m256i& s1, __m256i& s2, __m256i& s3) {
  const auto rotl = [](__m256i x, int k) {
    return _mm256_or_si256(_mm256_slli_epi64(x, k), _mm256_srli_epi64(x, 64 - k));
  };
  const __m256i r = _mm256_add_epi64(rotl(_mm256_add_epi64(s0, s3), 23), s0);
  const __m256i t = _mm256_slli_epi64(s1, 17);
  s2 = _mm256_xor_si256(s2, s0);
  s3 = _mm256_xor_si256(s3, s1);
  s1 = _mm256_xor_si256(s1, s2);
  s0 = _mm256_xor_si256(s0, s3);
  s2 = _mm256_xor_si256(s2, t);
  s3 = rotl(s3, 45);
  return r;
}

}  // namespace nimbus::simd
