#include "core/grid/tile_arena.h"

namespace nimbus {

TileArena::TileArena(size_t tile_bytes) : tile_bytes_(tile_bytes), used_(kBlockBytes) {}

void* TileArena::Allocate() {
  if (used_ + tile_bytes_ > kBlockBytes) NewBlock();
  void* tile = blocks_.back().as<char>() + used_;
  used_ += tile_bytes_;
  return tile;
}

void TileArena::NewBlock() {
  // Huge pages from the second block on (see the class comment).
  const bool huge = huge_first_ || !blocks_.empty();
  blocks_.emplace_back(kBlockBytes, huge);
  used_ = 0;
}

}  // namespace nimbus
