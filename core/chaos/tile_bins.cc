#include "core/chaos/tile_bins.h"

#include <algorithm>

namespace nimbus {
namespace {
// A flat lattice's counters, then a spare 16-counter line whose first
// counter is the discard counter (flat_discard()).
uint64_t FlatBytes(uint64_t voxels) { return (voxels + 16) * sizeof(uint32_t); }
}  // namespace

uint32_t TileBins::BinShift(Int3 resolution) {
  const uint64_t tiles = CountGrid::TileCountFor(resolution);
  uint32_t shift = 0;
  if (tiles > kSplitTiles)
    while ((tiles >> shift) > kBuckets) ++shift;
  return shift;
}

uint64_t TileBins::BinCount(Int3 resolution) {
  return ((CountGrid::TileCountFor(resolution) - 1) >> BinShift(resolution)) + 1;
}

TileBins::TileBins(CountGrid& grid, size_t capacity, bool direct, Int3 lattice,
                   uint32_t lattice_fold)
    : grid_(grid), direct_(direct), lattice_(lattice.x > 0 ? lattice : grid.resolution()),
      lattice_fold_(lattice_fold) {
  const uint64_t tiles = CountGrid::TileCountFor(grid.resolution());
  if (direct && Flat(lattice_)) {
    flat_voxels_ = uint32_t(uint64_t(lattice_.x) * lattice_.y * lattice_.z);
    // Huge pages: an attractor spread over the lattice touches most of its
    // 4 KiB pages anyway, each at the cost of a page fault (1024 per 4 MiB
    // picture, microseconds each), and Flush reads every page.
    flat_ = ZeroPages(size_t(FlatBytes(flat_voxels_)), /*huge=*/true);
    // Flushes write the attractor's tiles, usually most of the grid's few.
    grid.PreferHugePages();
    return;
  }
  if (direct) {
    // All null: the first visit of a tile asks the grid, which returns the
    // tile it may already hold.
    tiles_.assign(tiles, nullptr);
    return;
  }
  shift_ = BinShift(grid.resolution());
  pool_ = Pool(size_t(BinCount(grid.resolution())), capacity, /*huge_pages=*/true);
  if (shift_ > 0) split_ = SplitPool(size_t{1} << shift_, kSplitEntries, /*huge_pages=*/true);
}

TileBins::TileBins(SharedTiles& shared, CountGrid& grid, size_t capacity, uint32_t first_range)
    : TileBins(grid, capacity) {
  shared_ = &shared;
  first_range_ = first_range;
}

void TileBins::Refill(uint32_t bin) {
  // Drained here rather than by the pool's Refill: a shared grid takes its
  // locks range by range.
  if (pool_.exhausted()) Flush();
  pool_.Refill(bin, [](uint32_t, const uint32_t*, const uint32_t*) {});
}

void TileBins::Flush() {
  if (flat_) return DrainFlat();
  if (!shared_) {
    DrainBins(0, pool_.bins());
  } else {
    shared_->ForEachRange(first_range_,
                          [&](uint32_t first, uint32_t last) { DrainBins(first, last); });
  }
  pool_.Reset();
}

void TileBins::DrainBins(uint32_t first, uint32_t last) {
  if (shift_ == 0) return pool_.DrainBins(first, last, [&](uint32_t bin, auto b, auto e) {
    Apply(bin, b, e);
  });
  for (uint32_t bin = first; bin < last; ++bin) {
    split_first_ = uint64_t(bin) << shift_;
    pool_.DrainBins(bin, bin + 1, [&](uint32_t, auto b, auto e) { Split(b, e); });
    ApplySplit(split_first_);
  }
}

uint32_t* TileBins::Allocate(uint32_t tile) {
  // Past the grid's tile limit this is its scratch tile, as Apply would use.
  return tiles_[tile] = grid_.MutableTile(tile);
}

void TileBins::Apply(uint32_t bin, const uint32_t* begin, const uint32_t* end) {
  uint32_t* tile = TileOf(bin);
  if (!tile) return;
  for (const uint32_t* e = begin; e != end; ++e) tile[*e]++;
}

void TileBins::Split(const uint32_t* begin, const uint32_t* end) {
  Cursor16* cursors = split_.cursors();
  for (const uint32_t* e = begin; e != end; ++e) {
    const uint32_t t = *e >> 15;
    Cursor16& c = cursors[t];
    if (c.tail == c.end) [[unlikely]] {
      // A bin with more entries than the split pool holds: apply what it
      // has and go on.
      if (split_.exhausted()) ApplySplit(split_first_);
      split_.Refill(t, [](uint32_t, const uint16_t*, const uint16_t*) {});
    }
    *c.tail++ = uint16_t(*e & 0x7fff);
  }
}

void TileBins::ApplySplit(uint64_t first_tile) {
  split_.Drain([&](uint32_t t, const uint16_t* begin, const uint16_t* end) {
    uint32_t* tile = TileOf(first_tile + t);
    if (!tile) return;
    for (const uint16_t* e = begin; e != end; ++e) tile[*e]++;
  });
}

void TileBins::DrainFlat() {
  // 16 counters (a cache line) at a time: most lines no point reached, and
  // a line that one did is located by one division, then walked. A tile is
  // allocated in the grid exactly when a counter in it is not zero, as a
  // point landing there would have allocated it.
  uint32_t* flat = flat_.as<uint32_t>();
  const uint32_t ny = uint32_t(lattice_.y), nz = uint32_t(lattice_.z);
  const uint32_t mask = (1u << lattice_fold_) - 1;
  for (uint32_t i = 0; i < flat_voxels_; i += 16) {
    const uint32_t end = std::min<uint32_t>(i + 16, flat_voxels_);
    uint32_t any = 0;
    for (uint32_t j = i; j < end; ++j) any |= flat[j];
    if (!any) continue;
    uint32_t z = i % nz, y = i / nz % ny, x = i / nz / ny;
    for (uint32_t j = i; j < end; ++j) {
      if (const uint32_t n = flat[j]) {
        // Wraps modulo 2^32 as the increments themselves would.
        grid_.AddKey(grid_.Key(int(x), int(y >> lattice_fold_), int(z + (y & mask))), n);
        flat[j] = 0;
      }
      if (++z == nz) {
        z = 0;
        if (++y == ny) y = 0, ++x;
      }
    }
  }
}

uint64_t TileBins::MemoryBytes() const {
  if (flat_) return FlatBytes(flat_voxels_);
  if (direct_) return tiles_.capacity() * sizeof(uint32_t*);
  return pool_.MemoryBytes() + (shift_ > 0 ? split_.MemoryBytes() : 0);
}

uint64_t TileBins::Bytes(Int3 resolution, size_t capacity, bool direct) {
  const uint64_t tiles = CountGrid::TileCountFor(resolution);
  // A picture's lattice has no more voxels than its folded grid.
  const uint64_t voxels = uint64_t(resolution.x) * resolution.y * resolution.z;
  if (direct && Flat(resolution)) return FlatBytes(voxels);
  if (direct) return tiles * sizeof(uint32_t*);
  const uint32_t shift = BinShift(resolution);
  return Pool::Bytes(BinCount(resolution), capacity) +
         (shift > 0 ? SplitPool::Bytes(uint64_t{1} << shift, kSplitEntries) : 0);
}

}  // namespace nimbus
