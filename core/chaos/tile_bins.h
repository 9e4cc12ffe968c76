// Deferred, binned increments into a CountGrid: the write side of the fast
// chaos-game path.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "core/base/zero_pages.h"
#include "core/chaos/affine_walk.h"
#include "core/chaos/bin_pool.h"
#include "core/chaos/shared_tiles.h"
#include "core/grid/count_grid.h"

namespace nimbus {

/// @brief Collects voxel increments in bins as they are produced and
/// applies them tile by tile, so each 128 KiB tile is pulled into L2 once
/// per flush and then takes thousands of increments, instead of one cache
/// miss per increment. Entries are 32-bit (see walk::AffineWalk) and live in
/// blocks from a fixed pool; when the pool runs out every bin is applied and
/// the pool starts over. Memory is fixed at construction.
///
/// A grid of many tiles is partitioned in two passes (a radix partition):
/// the walk writes to at most kBuckets bins of 2^bin_shift consecutive
/// tiles each, whose cursors and open lines stay in L1, instead of to one
/// bin per tile, where every push misses the cache twice (the cursor, then
/// the stream's line) once a few thousand tiles are busy. A flush then
/// splits each bin by tile into a small second pool of 16-bit offsets and
/// applies that tile by tile.
///
/// In direct mode there are no bins: the kernels increment each voxel as
/// they go through a table of the grid's tile pointers. That wins when the
/// cache lines the attractor touches fit in the caches (a few hundred tiles
/// at most), where binning only adds a write and a read of every entry.
///
/// Direct mode on a lattice of at most kFlatVoxels voxels (a 1024^2
/// picture or 2D volume, a 128^3 volume) is flat: the kernels increment
/// one plain array over the walk's lattice, indexed (x * ny + y) * nz + z,
/// with neither tile arithmetic nor a table of tile pointers per point,
/// and Flush adds its non-zero counters into the grid (allocating the
/// tiles they lie in, as the increments would have) and zeroes them.
///
/// Not thread-safe: one per thread, each over its thread's CountGrid, or
/// all over one grid through a SharedTiles (binned mode only).
class TileBins {
 public:
  /// At most this many bins for the walk on grids of over kSplitTiles
  /// tiles; smaller grids bin by tile.
  static constexpr uint32_t kBuckets = 256;
  static constexpr uint64_t kSplitTiles = 4096;
  /// Direct mode is flat on lattices of at most this many voxels (8 MiB).
  static constexpr uint64_t kFlatVoxels = uint64_t{1} << 21;

  /// `capacity`: entries buffered before a flush (at least one block);
  /// unused in direct mode. `lattice`: the voxels the walk indexes (for
  /// flat mode), the grid's resolution by default; a picture's pixels
  /// (column, row) are stored at the grid's voxel (column, row >>
  /// `lattice_fold`, row & (2^lattice_fold - 1)) (ImagePlane).
  TileBins(CountGrid& grid, size_t capacity, bool direct = false, Int3 lattice = {},
           uint32_t lattice_fold = 0);
  /// Binned, over the grid `shared` guards, which other TileBins fill at
  /// the same time; flushes begin with range `first_range`
  /// (SharedTiles::ForEachRange), best a different one per thread.
  TileBins(SharedTiles& shared, CountGrid& grid, size_t capacity, uint32_t first_range);

  /// Cursors for walk::AffineWalk::bins and the shift that goes with them.
  walk::BinCursor* cursors() { return pool_.cursors(); }
  uint32_t bin_shift() const { return shift_; }
  /// Bins of a grid of `resolution`, and the shift that goes with them.
  static uint32_t BinShift(Int3 resolution);
  static uint64_t BinCount(Int3 resolution);

  /// Direct mode's table for walk::AffineWalk::tiles (null otherwise):
  /// tile t's counters, or null until Allocate(t).
  uint32_t** tiles() { return direct_ && !flat_ ? tiles_.data() : nullptr; }
  /// Flat direct mode's array for walk::AffineWalk::flat (null otherwise),
  /// and the index of its scratch counter (walk::AffineWalk::flat_discard).
  uint32_t* flat() { return flat_.as<uint32_t>(); }
  uint32_t flat_discard() const { return flat_voxels_; }
  /// Whether direct mode on this lattice is flat.
  static bool Flat(Int3 lattice) {
    return uint64_t(lattice.x) * uint64_t(lattice.y) * uint64_t(lattice.z) <= kFlatVoxels;
  }
  /// Tile t's counters, allocated if need be (walk::AffineWalk::allocate).
  uint32_t* Allocate(uint32_t tile);

  /// Gives `bin` a fresh block, flushing everything first if the pool is
  /// empty (walk::AffineWalk::refill).
  void Refill(uint32_t bin);
  /// Applies every buffered entry to the grid.
  void Flush();
  /// The grid outgrew its tile limit (CountGrid::overflowed()).
  bool overflowed() const { return shared_ ? shared_->overflowed() : grid_.overflowed(); }

  /// Bytes held: the pools and the bookkeeping.
  uint64_t MemoryBytes() const;
  /// What MemoryBytes() will be (at most) for a grid of `resolution` and
  /// `capacity`.
  static uint64_t Bytes(Int3 resolution, size_t capacity, bool direct = false);

 private:
  using Pool = BinPool<uint32_t, walk::BinCursor>;
  // The second pass: tile offsets within a bin, 16-bit local offsets.
  struct Cursor16 {
    uint16_t* tail = nullptr;
    uint16_t* end = nullptr;
  };
  using SplitPool = BinPool<uint16_t, Cursor16>;
  static constexpr size_t kSplitEntries = size_t{1} << 21;  // 4 MiB

  // Applies bins [first, last) and empties them (their blocks stay taken).
  void DrainBins(uint32_t first, uint32_t last);
  void Apply(uint32_t bin, const uint32_t* begin, const uint32_t* end);
  // The second pass for one block of a bin of several tiles.
  void Split(const uint32_t* begin, const uint32_t* end);
  // Applies the split pool to the tiles from `first_tile` on.
  void ApplySplit(uint64_t first_tile);
  // Flat mode's flush: adds the array's non-zero counters to the grid and
  // zeroes them.
  void DrainFlat();
  // Tile t's counters; null (drop the increments) past a shared grid's
  // tile limit.
  uint32_t* TileOf(uint64_t t) { return shared_ ? shared_->Tile(t) : grid_.MutableTile(t); }

  CountGrid& grid_;
  uint32_t shift_ = 0;  // tile-index bits below the bin index
  Pool pool_;           // none in direct mode
  SplitPool split_;     // with shift_ > 0
  uint64_t split_first_ = 0;  // the first tile of the bin being split
  bool direct_ = false;
  std::vector<uint32_t*> tiles_;  // direct mode: a copy of the grid's table
  // Flat mode: fresh zero pages (huge ones).
  ZeroPages flat_;
  uint32_t flat_voxels_ = 0;  // lattice voxels; the scratch counter follows
  Int3 lattice_;
  uint32_t lattice_fold_ = 0;
  SharedTiles* shared_ = nullptr;
  uint32_t first_range_ = 0;
};

}  // namespace nimbus
