// Run-time choice of SIMD paths. Shipped binaries target the x86-64
// baseline; wider kernels are compiled per file and picked here.
#pragma once

#include <string_view>

namespace nimbus {

enum class SimdLevel {
  kScalar,  // the x86-64 baseline (SSE2)
  kAvx2,
  kAvx512,  // AVX-512 F and DQ
};

/// The widest level this CPU and OS support.
SimdLevel DetectSimd();
/// The level kernels use: DetectSimd(), lowered by the environment variable
/// NIMBUS_SIMD=scalar or NIMBUS_SIMD=avx2 (for comparisons and for tracking
/// down a suspected SIMD difference). Read once.
SimdLevel ActiveSimd();
std::string_view SimdName(SimdLevel level);

}  // namespace nimbus
