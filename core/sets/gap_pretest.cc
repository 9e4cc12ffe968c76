#include "core/sets/gap_pretest.h"

#include "core/base/cpu_dispatch.h"

namespace nimbus::gap {
namespace portable {
#include "core/sets/gap_pretest_portable.inc"
}  // namespace portable

uint64_t NeedPortable(const Word& w) { return portable::Need(w); }

namespace {
// The AVX2 and AVX-512 levels also use BMI2 (pext, pdep) and POPCNT, which
// every such CPU has but cpu_dispatch does not check.
bool HasBitInstructions() {
#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
  return __builtin_cpu_supports("bmi") && __builtin_cpu_supports("bmi2") &&
         __builtin_cpu_supports("popcnt");
#else
  return false;
#endif
}
}  // namespace

NeedFn NeedKernel(int level) {
  const int best = HasBitInstructions() ? int(DetectSimd()) : int(SimdLevel::kScalar);
  const int use = level < best ? level : best;
  if (use >= int(SimdLevel::kAvx512)) return NeedAvx512;
  if (use >= int(SimdLevel::kAvx2)) return NeedAvx2;
  return NeedPortable;
}

NeedFn NeedKernel() {
  static const NeedFn fn = NeedKernel(int(ActiveSimd()));
  return fn;
}

}  // namespace nimbus::gap
