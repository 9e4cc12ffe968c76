// Deferred, binned increments into a CountGrid: the write side of the fast
// chaos-game path.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "core/chaos/affine_walk.h"
#include "core/chaos/bin_pool.h"
#include "core/grid/count_grid.h"

namespace nimbus {

/// @brief Collects voxel increments in per-tile bins as they are produced
/// and applies them bin by bin, so each 128 KiB tile is pulled into L2 once
/// per flush and then takes thousands of increments, instead of one cache
/// miss per increment. Entries are 32-bit (see walk::AffineWalk) and live in
/// blocks from a fixed pool; when the pool runs out every bin is applied and
/// the pool starts over. Memory is fixed at construction.
///
/// In direct mode there are no bins: the kernels increment each voxel as
/// they go through a table of the grid's tile pointers. That wins when the
/// cache lines the attractor touches fit in the caches (a few hundred tiles
/// at most), where binning only adds a write and a read of every entry.
///
/// Not thread-safe: one per thread, each over its thread's CountGrid.
class TileBins {
 public:
  /// At most this many bins; larger grids put 2^shift tiles in a bin.
  static constexpr uint32_t kMaxBins = BinPool<uint32_t, walk::BinCursor>::kMaxBins;

  /// `capacity`: entries buffered before a flush (at least one block);
  /// unused in direct mode.
  TileBins(CountGrid& grid, size_t capacity, bool direct = false);

  /// Cursors for walk::AffineWalk::bins and the shift that goes with them.
  walk::BinCursor* cursors() { return pool_.cursors(); }
  uint32_t bin_shift() const { return shift_; }

  /// Direct mode's table for walk::AffineWalk::tiles (null otherwise):
  /// tile t's counters, or null until Allocate(t).
  uint32_t** tiles() { return direct_ ? tiles_.data() : nullptr; }
  /// Tile t's counters, allocated if need be (walk::AffineWalk::allocate).
  uint32_t* Allocate(uint32_t tile);

  /// Gives `bin` a fresh block, flushing everything first if the pool is
  /// empty (walk::AffineWalk::refill).
  void Refill(uint32_t bin);
  /// Applies every buffered entry to the grid.
  void Flush();

  /// Bytes held: the pool and the bookkeeping.
  uint64_t MemoryBytes() const;
  /// What MemoryBytes() will be for a grid of `resolution` and `capacity`.
  static uint64_t Bytes(Int3 resolution, size_t capacity, bool direct = false);

 private:
  using Pool = BinPool<uint32_t, walk::BinCursor>;
  void Apply(uint32_t bin, const uint32_t* begin, const uint32_t* end);
  auto ApplyFn() {
    return [this](uint32_t bin, const uint32_t* begin, const uint32_t* end) {
      Apply(bin, begin, end);
    };
  }

  CountGrid& grid_;
  uint32_t shift_ = 0;  // tile-index bits below the bin index
  Pool pool_;           // none in direct mode
  bool direct_ = false;
  std::vector<uint32_t*> tiles_;  // direct mode: a copy of the grid's table
};

}  // namespace nimbus
