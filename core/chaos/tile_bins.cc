#include "core/chaos/tile_bins.h"

#include <sys/mman.h>

#include <algorithm>
#include <bit>
#include <cstdlib>
#include <new>

namespace nimbus {

namespace {

uint32_t ShiftFor(uint64_t tiles) {
  uint32_t shift = 0;
  while ((tiles >> shift) > TileBins::kMaxBins) ++shift;
  return shift;
}

uint64_t TileCount(Int3 r) { return CountGrid::TileCountFor(r); }

}  // namespace

uint32_t TileBins::BlockSize(size_t capacity, size_t bins) {
  // About four blocks per bin when every bin is busy: small enough that a
  // thin fractal's few busy bins can take most of the pool, large enough
  // that block hand-outs are rare.
  const uint64_t per = std::max<uint64_t>(capacity / (4 * std::max<size_t>(bins, 1)), 1);
  return uint32_t(std::clamp<uint64_t>(std::bit_floor(per), 256, 4096));
}

TileBins::TileBins(CountGrid& grid, size_t capacity, bool direct)
    : grid_(grid), direct_(direct) {
  const uint64_t tiles = TileCount(grid.resolution());
  if (direct) {
    // All null: the first visit of a tile asks the grid, which returns the
    // tile it may already hold.
    tiles_.assign(tiles, nullptr);
    return;
  }
  shift_ = ShiftFor(tiles);
  const size_t bins = size_t(((tiles - 1) >> shift_) + 1);
  block_ = BlockSize(capacity, bins);
  blocks_ = uint32_t(std::max<size_t>(capacity / block_, 1));
  // Not value-initialised: pages are touched only as blocks fill. A pool of
  // thousands of bins writes to as many pages at once: huge pages spare the
  // TLB (a hint; without THP it keeps 4 KiB pages).
  const size_t bytes = size_t(blocks_) * block_ * sizeof(uint32_t);
  constexpr size_t kHuge = size_t{2} << 20;
  const size_t rounded = (bytes + kHuge - 1) / kHuge * kHuge;
  pool_.reset(static_cast<uint32_t*>(std::aligned_alloc(kHuge, rounded)));
  if (!pool_) throw std::bad_alloc();
  if (rounded > kHuge) madvise(pool_.get(), rounded, MADV_HUGEPAGE);
  next_.assign(blocks_, -1);
  head_.assign(bins, -1);
  last_.assign(bins, -1);
  cursors_.resize(bins);
}

void TileBins::Refill(uint32_t bin) {
  if (used_ == blocks_) Flush();
  const int32_t block = int32_t(used_++);
  if (last_[bin] < 0)
    head_[bin] = block;
  else
    next_[last_[bin]] = block;
  last_[bin] = block;
  next_[block] = -1;
  uint32_t* begin = pool_.get() + size_t(block) * block_;
  cursors_[bin] = {begin, begin + block_};
}

uint32_t* TileBins::Allocate(uint32_t tile) {
  // Past the grid's tile limit this is its scratch tile, as Apply would use.
  return tiles_[tile] = grid_.MutableTile(tile);
}

void TileBins::Apply(uint32_t bin, const uint32_t* begin, const uint32_t* end) {
  if (shift_ == 0) {
    uint32_t* tile = grid_.MutableTile(bin);
    for (const uint32_t* e = begin; e != end; ++e) tile[*e]++;
    return;
  }
  const uint64_t first = uint64_t(bin) << shift_;
  uint32_t current = ~0u;
  uint32_t* tile = nullptr;
  for (const uint32_t* e = begin; e != end; ++e) {
    const uint32_t t = *e >> 15;
    if (t != current) {
      current = t;
      tile = grid_.MutableTile(first + t);
    }
    tile[*e & 0x7fff]++;
  }
}

void TileBins::Flush() {
  for (uint32_t bin = 0; bin < head_.size(); ++bin) {
    for (int32_t b = head_[bin]; b >= 0; b = next_[b]) {
      const uint32_t* begin = pool_.get() + size_t(b) * block_;
      Apply(bin, begin, b == last_[bin] ? cursors_[bin].tail : begin + block_);
    }
    head_[bin] = last_[bin] = -1;
    cursors_[bin] = {};
  }
  used_ = 0;
}

uint64_t TileBins::MemoryBytes() const {
  if (direct_) return tiles_.capacity() * sizeof(uint32_t*);
  return uint64_t(blocks_) * block_ * sizeof(uint32_t) + next_.capacity() * sizeof(int32_t) +
         (head_.capacity() + last_.capacity()) * sizeof(int32_t) +
         cursors_.capacity() * sizeof(walk::BinCursor);
}

uint64_t TileBins::Bytes(Int3 resolution, size_t capacity, bool direct) {
  const uint64_t tiles = TileCount(resolution);
  if (direct) return tiles * sizeof(uint32_t*);
  const uint64_t bins = ((tiles - 1) >> ShiftFor(tiles)) + 1;
  const uint32_t block = BlockSize(capacity, bins);
  const uint64_t blocks = std::max<uint64_t>(capacity / block, 1);
  return blocks * block * sizeof(uint32_t) + blocks * sizeof(int32_t) +
         bins * (2 * sizeof(int32_t) + sizeof(walk::BinCursor));
}

}  // namespace nimbus
