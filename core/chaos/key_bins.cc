#include "core/chaos/key_bins.h"

#include <bit>

namespace nimbus {

namespace {

// Applies a run of keys of one tile; returns where the run ends. The
// variants keep the common cases (plain counts; counts and colour) free of
// the weight and colour arithmetic they do not need.
constexpr int kAhead = 64;

template <bool kColor, bool kWeighted>
const uint64_t* ApplyTile(CountGrid& grid, const uint64_t* e, const uint64_t* end) {
  const uint64_t tile = (*e & CountGrid::kVoxelMask) >> 15;
  uint32_t* counts = grid.MutableTile(tile);
  uint64_t* colors = kColor ? grid.MutableColorTile(tile) : nullptr;
  for (; e != end && ((*e & CountGrid::kVoxelMask) >> 15) == tile; ++e) {
    if (end - e > kAhead) {
      const uint32_t ahead = uint32_t(e[kAhead] & 0x7fff);
      __builtin_prefetch(counts + ahead, 1);
      if constexpr (kColor) __builtin_prefetch(colors + ahead, 1);
    }
    const uint32_t off = uint32_t(*e & 0x7fff);
    const uint32_t add = kWeighted ? CountGrid::WeightOf(*e) : 1;
    counts[off] += add;
    if constexpr (kColor) colors[off] += uint64_t(add) * (*e >> CountGrid::kColorShift);
  }
  return e;
}

template <bool kColor, bool kWeighted>
void ApplyAll(CountGrid& grid, const uint64_t* e, const uint64_t* end) {
  while (e != end) e = ApplyTile<kColor, kWeighted>(grid, e, end);
}

}  // namespace

KeyBins::KeyBins(CountGrid& grid, size_t capacity, bool weighted)
    : grid_(grid), weighted_(weighted) {
  const uint64_t tiles = CountGrid::TileCountFor(grid.resolution());
  shift_ = 15 + Pool::TileShift(tiles);
  pool_ = Pool(size_t(Pool::BinCount(tiles)), capacity, /*huge_pages=*/false);
}

uint64_t KeyBins::AddLanes(const uint64_t* key, uint64_t lanes) {
  uint64_t added = 0;
  // Bits walked one by one: the x86-64 baseline has no popcnt.
  for (; lanes; lanes &= lanes - 1, ++added) Add(key[std::countr_zero(lanes)]);
  return added;
}

void KeyBins::Refill(uint32_t bin) { pool_.Refill(bin, ApplyFn()); }

void KeyBins::Apply(const uint64_t* begin, const uint64_t* end) {
  if (grid_.has_color())
    weighted_ ? ApplyAll<true, true>(grid_, begin, end) : ApplyAll<true, false>(grid_, begin, end);
  else
    weighted_ ? ApplyAll<false, true>(grid_, begin, end)
              : ApplyAll<false, false>(grid_, begin, end);
}

void KeyBins::Flush() { pool_.Drain(ApplyFn()); }

uint64_t KeyBins::MemoryBytes() const { return pool_.MemoryBytes(); }

uint64_t KeyBins::Bytes(Int3 resolution, size_t capacity) {
  return Pool::Bytes(Pool::BinCount(CountGrid::TileCountFor(resolution)), capacity);
}

}  // namespace nimbus
