#include "core/chaos/shared_tiles.h"

namespace nimbus {

SharedTiles::SharedTiles(CountGrid& grid, uint32_t bins)
    : grid_(grid), bins_(bins), locks_(new std::mutex[kRanges]) {}

uint32_t* SharedTiles::Tile(uint64_t t) {
  // Only the holder of t's range writes entry t of the table, so reading
  // it needs no lock; allocating does, as the arena is the grid's.
  if (uint32_t* p = grid_.MutableTileOrNull(t)) return p;
  std::lock_guard<std::mutex> hold(alloc_);
  uint32_t* p = grid_.MutableTile(t);
  if (!grid_.overflowed()) return p;
  // Past the limit the grid hands out one scratch tile, which two threads
  // would write at once: drop the increments instead, the run is over.
  overflowed_.store(true, std::memory_order_relaxed);
  return nullptr;
}

}  // namespace nimbus
