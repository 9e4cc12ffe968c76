#include "core/base/cpu_dispatch.h"

#include <cstdlib>
#include <cstring>

namespace nimbus {

SimdLevel DetectSimd() {
#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
  // libgcc's check includes the OS saving the YMM registers (XGETBV).
  if (__builtin_cpu_supports("avx2")) return SimdLevel::kAvx2;
#endif
  return SimdLevel::kScalar;
}

SimdLevel ActiveSimd() {
  static const SimdLevel level = [] {
    const char* env = std::getenv("NIMBUS_SIMD");
    if (env && std::strcmp(env, "scalar") == 0) return SimdLevel::kScalar;
    return DetectSimd();
  }();
  return level;
}

std::string_view SimdName(SimdLevel level) {
  switch (level) {
    case SimdLevel::kAvx2:
      return "avx2";
    case SimdLevel::kScalar:
      break;
  }
  return "scalar";
}

}  // namespace nimbus
