#include "core/chaos/key_bins.h"

#include <algorithm>
#include <bit>

namespace nimbus {

namespace {

// Tile-index bits dropped so that at most kMaxBins bins remain.
uint32_t TileShift(uint64_t tiles) {
  uint32_t shift = 0;
  while ((tiles >> shift) > KeyBins::kMaxBins) ++shift;
  return shift;
}

uint64_t BinCount(uint64_t tiles) { return ((tiles - 1) >> TileShift(tiles)) + 1; }

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

uint32_t KeyBins::BlockSize(size_t capacity, size_t bins) {
  // About four blocks per bin when every bin is busy: small enough that a
  // thin fractal's few busy bins can take most of the pool, large enough
  // that block hand-outs are rare.
  const uint64_t per = std::max<uint64_t>(capacity / (4 * std::max<size_t>(bins, 1)), 1);
  return uint32_t(std::clamp<uint64_t>(std::bit_floor(per), 256, 4096));
}

KeyBins::KeyBins(CountGrid& grid, size_t capacity, bool weighted)
    : grid_(grid), weighted_(weighted) {
  const uint64_t tiles = CountGrid::TileCountFor(grid.resolution());
  shift_ = 15 + TileShift(tiles);
  const size_t bins = size_t(BinCount(tiles));
  block_ = BlockSize(capacity, bins);
  blocks_ = uint32_t(std::max<size_t>(capacity / block_, 1));
  // Not value-initialised: pages are touched only as blocks fill.
  pool_.reset(new uint64_t[size_t(blocks_) * block_]);
  next_.assign(blocks_, -1);
  head_.assign(bins, -1);
  last_.assign(bins, -1);
  cursors_.resize(bins);
}

void KeyBins::Refill(uint32_t bin) {
  if (used_ == blocks_) Flush();
  const int32_t block = int32_t(used_++);
  if (last_[bin] < 0)
    head_[bin] = block;
  else
    next_[last_[bin]] = block;
  last_[bin] = block;
  next_[block] = -1;
  uint64_t* begin = pool_.get() + size_t(block) * block_;
  cursors_[bin] = {begin, begin + block_};
}

void KeyBins::Apply(const uint64_t* begin, const uint64_t* end) {
  if (grid_.has_color())
    weighted_ ? ApplyAll<true, true>(grid_, begin, end) : ApplyAll<true, false>(grid_, begin, end);
  else
    weighted_ ? ApplyAll<false, true>(grid_, begin, end)
              : ApplyAll<false, false>(grid_, begin, end);
}

void KeyBins::Flush() {
  for (uint32_t bin = 0; bin < head_.size(); ++bin) {
    for (int32_t b = head_[bin]; b >= 0; b = next_[b]) {
      const uint64_t* begin = pool_.get() + size_t(b) * block_;
      Apply(begin, b == last_[bin] ? cursors_[bin].tail : begin + block_);
    }
    head_[bin] = last_[bin] = -1;
    cursors_[bin] = {};
  }
  used_ = 0;
}

uint64_t KeyBins::MemoryBytes() const {
  return uint64_t(blocks_) * block_ * sizeof(uint64_t) + next_.capacity() * sizeof(int32_t) +
         (head_.capacity() + last_.capacity()) * sizeof(int32_t) +
         cursors_.capacity() * sizeof(Cursor);
}

uint64_t KeyBins::Bytes(Int3 resolution, size_t capacity) {
  const uint64_t bins = BinCount(CountGrid::TileCountFor(resolution));
  const uint32_t block = BlockSize(capacity, bins);
  const uint64_t blocks = std::max<uint64_t>(capacity / block, 1);
  return blocks * block * sizeof(uint64_t) + blocks * sizeof(int32_t) +
         bins * (2 * sizeof(int32_t) + sizeof(Cursor));
}

}  // namespace nimbus
