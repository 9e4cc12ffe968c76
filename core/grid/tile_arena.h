// Zeroed tiles carved from 2 MiB blocks, for CountGrid's counters.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "core/base/zero_pages.h"

namespace nimbus {

/// @brief Hands out zeroed, fixed-size tiles from 2 MiB-aligned blocks
/// mapped straight from the kernel (fresh pages are zero, so no memset).
/// From the second block on, the blocks ask for transparent huge pages:
/// writers that scatter increments over a hundred tiles otherwise miss the
/// TLB on nearly every one (4 KiB pages), while one 2 MiB page covers 16
/// tiles. A grid of at most one block keeps 4 KiB pages and so its
/// resident memory. Tiles are freed with the arena only.
class TileArena {
 public:
  static constexpr size_t kBlockBytes = size_t{2} << 20;

  /// `tile_bytes` must divide kBlockBytes.
  explicit TileArena(size_t tile_bytes);

  /// A zeroed tile; throws std::bad_alloc when the kernel has no memory.
  void* Allocate();
  /// Huge pages from the first block on, for grids known to fill it.
  void PreferHugePages() { huge_first_ = true; }

 private:
  void NewBlock();

  size_t tile_bytes_;
  size_t used_ = 0;  // bytes handed out from the last block
  bool huge_first_ = false;
  std::vector<ZeroPages> blocks_;
};

}  // namespace nimbus
