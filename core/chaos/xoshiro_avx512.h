// @brief xoshiro256++ (core/base/random.h's Rng::Next) on eight streams at
// once, one per 64-bit lane, for the AVX-512 kernels. Include only from
// translation units compiled for AVX-512.
#pragma once

#include <immintrin.h>

namespace nimbus::simd {

/// The eight streams' next outputs; advances the state (s0..s3 hold lane
/// l's words s[0..3]).
inline __m512i XoshiroNext(__m512i& s0, __m512i& s1, __m512i& s2, __m512i& s3) {
  const __m512i r = _mm512_add_epi64(_mm512_rol_epi64(_mm512_add_epi64(s0, s3), 23), s0);
  const __m512i t = _mm512_slli_epi64(s1, 17);
  s2 = _mm512_xor_si512(s2, s0);
  s3 = _mm512_xor_si512(s3, s1);
  s1 = _mm512_xor_si512(s1, s2);
  s0 = _mm512_xor_si512(s0, s3);
  s2 = _mm512_xor_si512(s2, t);
  s3 = _mm512_rol_epi64(s3, 45);
  return r;
}

}  // namespace nimbus::simd
