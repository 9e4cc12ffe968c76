#include "core/chaos/tile_bins.h"

namespace nimbus {

TileBins::TileBins(CountGrid& grid, size_t capacity, bool direct)
    : grid_(grid), direct_(direct) {
  const uint64_t tiles = CountGrid::TileCountFor(grid.resolution());
  if (direct) {
    // All null: the first visit of a tile asks the grid, which returns the
    // tile it may already hold.
    tiles_.assign(tiles, nullptr);
    return;
  }
  shift_ = Pool::TileShift(tiles);
  pool_ = Pool(size_t(Pool::BinCount(tiles)), capacity, /*huge_pages=*/true);
}

void TileBins::Refill(uint32_t bin) { pool_.Refill(bin, ApplyFn()); }

void TileBins::Flush() { pool_.Drain(ApplyFn()); }

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

uint64_t TileBins::MemoryBytes() const {
  return direct_ ? tiles_.capacity() * sizeof(uint32_t*) : pool_.MemoryBytes();
}

uint64_t TileBins::Bytes(Int3 resolution, size_t capacity, bool direct) {
  const uint64_t tiles = CountGrid::TileCountFor(resolution);
  return direct ? tiles * sizeof(uint32_t*) : Pool::Bytes(Pool::BinCount(tiles), capacity);
}

}  // namespace nimbus
