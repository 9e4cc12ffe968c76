#include "core/grid/count_grid.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <cstring>
#include <limits>
#include <new>

namespace nimbus {

namespace {
int CeilDiv(int a, int b) { return (a + b - 1) / b; }
}  // namespace

namespace {
Int3 StorageTiles(Int3 resolution) {
  const Int3 s = CountGrid::StorageResolution(resolution);
  return {CeilDiv(s.x, CountGrid::kTileDim), CeilDiv(s.y, CountGrid::kTileDim),
          CeilDiv(s.z, CountGrid::kTileDim)};
}
}  // namespace

CountGrid::CountGrid(Int3 resolution, bool with_color)
    : res_(resolution),
      tiles_(StorageTiles(resolution)),
      fold_shift_(Folds(resolution) ? kTileLog2 : 0),
      fold_mask_(Folds(resolution) ? kTileDim - 1 : 0),
      with_color_(with_color),
      table_(size_t(tiles_.x) * tiles_.y * tiles_.z) {
  if (with_color_) color_.resize(table_.size());
}

uint64_t CountGrid::TileCountFor(Int3 resolution) {
  const Int3 t = StorageTiles(resolution);
  return uint64_t(t.x) * uint64_t(t.y) * uint64_t(t.z);
}

CountGrid::CountGrid(CountGrid&&) noexcept = default;
CountGrid& CountGrid::operator=(CountGrid&&) noexcept = default;
CountGrid::~CountGrid() = default;

uint32_t* CountGrid::Allocate(uint64_t tile) {
  if (tile_limit_ > 0 && allocated_ >= tile_limit_) {
    overflowed_ = true;
    if (!spill_) {
      spill_ = static_cast<uint32_t*>(arena_.Allocate());
      if (with_color_) spill_color_ = static_cast<uint64_t*>(color_arena_.Allocate());
    }
    return spill_;
  }
  table_[tile] = static_cast<uint32_t*>(arena_.Allocate());
  if (with_color_) color_[tile] = static_cast<uint64_t*>(color_arena_.Allocate());
  ++allocated_;
  return table_[tile];
}

uint32_t CountGrid::Get(int x, int y, int z) const {
  const uint64_t key = Key(x, y, z);
  const auto& t = table_[key >> 15];
  return t ? t[key & 0x7fff] : 0;
}

uint64_t CountGrid::GetColorSum(int x, int y, int z) const {
  if (!with_color_) return 0;
  const uint64_t key = Key(x, y, z);
  const auto& t = color_[key >> 15];
  return t ? t[key & 0x7fff] : 0;
}

void CountGrid::Merge(const CountGrid& other) {
  for (size_t t = 0; t < other.table_.size(); ++t) {
    if (!other.table_[t]) continue;
    AddTile(t, other.table_[t], other.with_color_ ? other.color_[t] : nullptr);
  }
}

void CountGrid::AddTile(uint64_t t, const uint32_t* src, const uint64_t* colors) {
  if (!table_[t]) Allocate(t);
  if (with_color_ && colors) {
    uint64_t* dst = color_[t];
    for (int i = 0; i < kTileVoxels; ++i) dst[i] += colors[i];
  }
  uint32_t* dst = table_[t];
  for (int i = 0; i < kTileVoxels; ++i) {
    const uint64_t s = uint64_t(dst[i]) + src[i];
    dst[i] = s > std::numeric_limits<uint32_t>::max() ? std::numeric_limits<uint32_t>::max()
                                                      : uint32_t(s);
  }
}

CountGrid::Sums CountGrid::MaxAndTotal() const {
  return tbb::parallel_reduce(
      tbb::blocked_range<size_t>(0, table_.size(), 16), Sums{},
      [&](const tbb::blocked_range<size_t>& r, Sums s) {
        for (size_t t = r.begin(); t < r.end(); ++t) {
          const uint32_t* v = table_[t];
          if (!v) continue;
          // Plain reductions vectorise; std::max_element's index does not.
          uint32_t m = 0;
          uint64_t sum = 0;
          for (int i = 0; i < kTileVoxels; ++i) m = std::max(m, v[i]), sum += v[i];
          s.max = std::max(s.max, m), s.total += sum;
        }
        return s;
      },
      [](Sums a, Sums b) {
        return Sums{std::max(a.max, b.max), a.total + b.total};
      });
}

size_t CountGrid::MemoryBytes() const {
  return table_.size() * sizeof(table_[0]) * (with_color_ ? 2 : 1) +
         allocated_ * TileBytes(with_color_);
}

uint64_t CountGrid::BoundedMemoryBytes(Int3 r, uint64_t max_tiles, bool with_color) {
  const uint64_t tiles = TileCountFor(r);
  return tiles * sizeof(void*) * (with_color ? 2 : 1) +
         std::min(tiles, max_tiles) * TileBytes(with_color);
}

uint64_t CountGrid::MaxMemoryBytes(Int3 r) {
  const uint64_t tiles = TileCountFor(r);
  return tiles * (sizeof(void*) + sizeof(uint32_t) * kTileVoxels);
}

}  // namespace nimbus
