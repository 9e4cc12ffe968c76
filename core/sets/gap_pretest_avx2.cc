// The portable pretest built for the AVX2 dispatch level: with BMI1, BMI2
// and POPCNT the bit loops use tzcnt, blsr and popcnt instead of their
// baseline sequences. Same source, so the same mask.
#include "core/sets/gap_pretest.h"

namespace nimbus::gap {
namespace avx2 {
#include "core/sets/gap_pretest_portable.inc"
}  // namespace avx2

uint64_t NeedAvx2(const Word& w) { return avx2::Need(w); }

}  // namespace nimbus::gap
