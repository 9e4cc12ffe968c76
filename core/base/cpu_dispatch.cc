#include "core/base/cpu_dispatch.h"

#include <algorithm>
#include <cstdlib>
#include <cstring>

namespace nimbus {

SimdLevel DetectSimd() {
#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
  // libgcc's checks include the OS saving the YMM and ZMM registers (XGETBV).
  if (__builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512dq"))
    return SimdLevel::kAvx512;
  if (__builtin_cpu_supports("avx2")) return SimdLevel::kAvx2;
#endif
  return SimdLevel::kScalar;
}

SimdLevel ActiveSimd() {
  static const SimdLevel level = [] {
    const char* env = std::getenv("NIMBUS_SIMD");
    const SimdLevel best = DetectSimd();
    if (env && std::strcmp(env, "scalar") == 0) return SimdLevel::kScalar;
    if (env && std::strcmp(env, "avx2") == 0) return std::min(best, SimdLevel::kAvx2);
    return best;
  }();
  return level;
}

std::string_view SimdName(SimdLevel level) {
  switch (level) {
    case SimdLevel::kAvx512:
      return "avx512";
    case SimdLevel::kAvx2:
      return "avx2";
    case SimdLevel::kScalar:
      break;
  }
  return "scalar";
}

}  // namespace nimbus
