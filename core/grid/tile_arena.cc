#include "core/grid/tile_arena.h"

#include <sys/mman.h>

#include <cstdint>
#include <new>

namespace nimbus {

TileArena::TileArena(size_t tile_bytes) : tile_bytes_(tile_bytes), used_(kBlockBytes) {}

void TileArena::Unmap::operator()(char* p) const { munmap(p, kBlockBytes); }

void* TileArena::Allocate() {
  if (used_ + tile_bytes_ > kBlockBytes) NewBlock();
  void* tile = blocks_.back().get() + used_;
  used_ += tile_bytes_;
  return tile;
}

void TileArena::NewBlock() {
  // Map twice the block and keep its aligned middle: a huge page needs a
  // 2 MiB-aligned range.
  void* p = mmap(nullptr, 2 * kBlockBytes, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS,
                 -1, 0);
  if (p == MAP_FAILED) throw std::bad_alloc();
  const uintptr_t start = uintptr_t(p);
  const uintptr_t aligned = (start + kBlockBytes - 1) & ~uintptr_t(kBlockBytes - 1);
  if (aligned > start) munmap(p, aligned - start);
  const uintptr_t end = start + 2 * kBlockBytes;
  if (end > aligned + kBlockBytes) munmap(reinterpret_cast<void*>(aligned + kBlockBytes),
                                          end - (aligned + kBlockBytes));
  char* block = reinterpret_cast<char*>(aligned);
  // A hint: without THP the block simply keeps 4 KiB pages.
  if (!blocks_.empty()) madvise(block, kBlockBytes, MADV_HUGEPAGE);
  blocks_.emplace_back(block);
  used_ = 0;
}

}  // namespace nimbus
