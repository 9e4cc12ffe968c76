// Deferred CountGrid keys binned by tile: the write side of the general
// (flame, chain, splatting, colour) chaos-game path.
#pragma once

#include <cstddef>
#include <cstdint>

#include "core/chaos/bin_pool.h"
#include "core/grid/count_grid.h"

namespace nimbus {

/// @brief Collects whole CountGrid keys (voxel, weight and colour bits) in
/// per-tile bins as they are produced and applies them bin by bin, so a
/// tile's counters and colour sums are pulled into L2 once per flush and
/// then take thousands of increments, with the tile pointers resolved once
/// per run of keys of one tile: no sorting pass. Keys live in blocks from a
/// fixed pool (BinPool, as TileBins' entries do); when the pool runs out every bin
/// is applied and the pool starts over. Counts and colour sums are integer
/// sums, so the order of application changes nothing.
///
/// Not thread-safe: one per thread, each over its thread's CountGrid.
class KeyBins {
 public:
  /// `capacity`: keys buffered before a flush (at least one block).
  /// `weighted`: keys may carry a weight (CountGrid::WithWeight).
  KeyBins(CountGrid& grid, size_t capacity, bool weighted);

  void Add(uint64_t key) {
    const uint32_t bin = uint32_t((key & CountGrid::kVoxelMask) >> shift_);
    Cursor& c = pool_.cursors()[bin];
    if (c.tail == c.end) [[unlikely]]
      Refill(bin);
    *c.tail++ = key;
  }
  /// Adds key[i] for every set bit i of `lanes` (a plot round's landed
  /// lanes); returns how many. Out of line on purpose: in a small function
  /// the loop's state stays in registers, where inlined into the caller's
  /// round loop it went through the stack on every key.
  uint64_t AddLanes(const uint64_t* key, uint64_t lanes);
  /// Applies every buffered key to the grid.
  void Flush();

  /// Bytes held: the pool and the bookkeeping.
  uint64_t MemoryBytes() const;
  /// What MemoryBytes() will be for a grid of `resolution` and `capacity`.
  static uint64_t Bytes(Int3 resolution, size_t capacity);

 private:
  struct Cursor {
    uint64_t* tail = nullptr;
    uint64_t* end = nullptr;
  };
  using Pool = BinPool<uint64_t, Cursor>;
  // Gives `bin` a fresh block, flushing everything first if the pool is empty.
  void Refill(uint32_t bin);
  void Apply(const uint64_t* begin, const uint64_t* end);
  auto ApplyFn() {
    return [this](uint32_t, const uint64_t* begin, const uint64_t* end) { Apply(begin, end); };
  }

  CountGrid& grid_;
  bool weighted_ = false;
  uint32_t shift_ = 15;  // key bits below the bin index
  Pool pool_;
};

}  // namespace nimbus
