#include "core/chaos/packed_adds.h"

#include <bit>

#include "core/grid/count_grid.h"

namespace nimbus::packed {

namespace {

uint32_t HoldScalar(const uint64_t* words, const uint64_t* key, uint64_t lanes, uint64_t* hold) {
  uint32_t n = 0;
  // Bits walked one by one: the x86-64 baseline has no popcnt.
  for (; lanes; lanes &= lanes - 1) {
    const uint64_t k = key[std::countr_zero(lanes)];
    __builtin_prefetch(words + (k & CountGrid::kVoxelMask), 1);
    hold[n++] = k;
  }
  return n;
}

template <bool kWeighted>
uint64_t ApplyScalarAs(uint64_t* words, const uint64_t* held, uint32_t n) {
  uint64_t touched = 0;
  for (uint32_t i = 0; i < n; ++i) {
    const uint64_t k = held[i];
    const uint64_t add = kWeighted ? CountGrid::WeightOf(k) : 1;
    words[k & CountGrid::kVoxelMask] += (add << kCountShift) + add * (k >> CountGrid::kColorShift);
    touched |= uint64_t{1} << ((k & CountGrid::kVoxelMask) >> 15);
  }
  return touched;
}

uint64_t ApplyScalar(uint64_t* words, const uint64_t* held, uint32_t n, bool weighted) {
  return weighted ? ApplyScalarAs<true>(words, held, n) : ApplyScalarAs<false>(words, held, n);
}

constexpr Loops kScalar{HoldScalar, ApplyScalar};

}  // namespace

const Loops& LoopsFor(SimdLevel level) {
  return level == SimdLevel::kAvx512 ? LoopsAvx512() : kScalar;
}

}  // namespace nimbus::packed
