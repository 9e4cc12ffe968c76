// @brief sin over arrays, with SLEEF's vector functions where the CPU has
// AVX2 or AVX-512 (core/base/cpu_dispatch.h) and the C library's sin
// otherwise. SLEEF's u10 functions are within 1 ulp of the true value and
// the C library's within 1 ulp too, so the two may differ in the last bit
// or two: callers that need the C library's exact result use this only
// where that difference provably cannot show (Palette::EvalFloats).
//
//   double x[n], s[n];
//   SinMany(x, s, n);  // s[k] ~ sin(x[k]), within 1 ulp
#pragma once

#include <cstddef>

#include "core/base/cpu_dispatch.h"

namespace nimbus {

/// s[k] = sin(x[k]) for k < n, at ActiveSimd()'s level.
void SinMany(const double* x, double* s, size_t n);
/// The same at `level` (at most DetectSimd()): for tests.
void SinManyAt(SimdLevel level, const double* x, double* s, size_t n);

namespace sine_internal {
void SinAvx2(const double* x, double* s, size_t n);
void SinAvx512(const double* x, double* s, size_t n);
}  // namespace sine_internal

}  // namespace nimbus
