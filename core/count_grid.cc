#include "core/count_grid.h"

#include <algorithm>
#include <cstring>
#include <limits>

namespace nimbus {

namespace {
int CeilDiv(int a, int b) { return (a + b - 1) / b; }
}  // namespace

CountGrid::CountGrid(Int3 resolution)
    : res_(resolution),
      tiles_{CeilDiv(resolution.x, kTileDim), CeilDiv(resolution.y, kTileDim),
             CeilDiv(resolution.z, kTileDim)},
      table_(size_t(tiles_.x) * tiles_.y * tiles_.z) {}

CountGrid::CountGrid(CountGrid&&) noexcept = default;
CountGrid& CountGrid::operator=(CountGrid&&) noexcept = default;
CountGrid::~CountGrid() = default;

void CountGrid::Allocate(uint64_t tile) {
  table_[tile].reset(new uint32_t[kTileVoxels]());
  ++allocated_;
}

void CountGrid::AddKeys(const uint64_t* keys, size_t n, std::vector<uint64_t>& scratch) {
  // Small batches or tiny grids gain nothing from binning.
  if (n < 4096 || table_.size() <= 8) {
    for (size_t i = 0; i < n; ++i) AddKey(keys[i]);
    return;
  }
  // One counting-sort pass on the tile index, bucketed to at most 1024 bins,
  // then apply bin by bin: each bin touches few tiles, which stay in L2.
  const size_t tiles = table_.size();
  int shift = 0;
  while ((tiles >> shift) > 1024) ++shift;
  const size_t bins = (tiles >> shift) + 1;
  std::vector<uint32_t> offsets(bins + 1, 0);
  for (size_t i = 0; i < n; ++i) offsets[(keys[i] >> (15 + shift)) + 1]++;
  for (size_t b = 0; b < bins; ++b) offsets[b + 1] += offsets[b];
  scratch.resize(n);
  std::vector<uint32_t> cursor(offsets.begin(), offsets.end() - 1);
  for (size_t i = 0; i < n; ++i) scratch[cursor[keys[i] >> (15 + shift)]++] = keys[i];
  for (size_t i = 0; i < n; ++i) AddKey(scratch[i]);
}

uint32_t CountGrid::Get(int x, int y, int z) const {
  const uint64_t key = Key(x, y, z);
  const auto& t = table_[key >> 15];
  return t ? t[key & 0x7fff] : 0;
}

void CountGrid::Merge(const CountGrid& other) {
  for (size_t t = 0; t < other.table_.size(); ++t) {
    if (!other.table_[t]) continue;
    if (!table_[t]) Allocate(t);
    uint32_t* dst = table_[t].get();
    const uint32_t* src = other.table_[t].get();
    for (int i = 0; i < kTileVoxels; ++i) {
      const uint64_t s = uint64_t(dst[i]) + src[i];
      dst[i] = s > std::numeric_limits<uint32_t>::max() ? std::numeric_limits<uint32_t>::max()
                                                        : uint32_t(s);
    }
  }
}

uint64_t CountGrid::Total() const {
  uint64_t total = 0;
  ForEachTile([&](Int3, const uint32_t* t) {
    for (int i = 0; i < kTileVoxels; ++i) total += t[i];
  });
  return total;
}

uint32_t CountGrid::Max() const {
  uint32_t m = 0;
  ForEachTile([&](Int3, const uint32_t* t) { m = std::max(m, *std::max_element(t, t + kTileVoxels)); });
  return m;
}

size_t CountGrid::MemoryBytes() const {
  return table_.size() * sizeof(table_[0]) + allocated_ * sizeof(uint32_t) * kTileVoxels;
}

uint64_t CountGrid::MaxMemoryBytes(Int3 r) {
  const uint64_t tiles = uint64_t(CeilDiv(r.x, kTileDim)) * CeilDiv(r.y, kTileDim) *
                         CeilDiv(r.z, kTileDim);
  return tiles * (sizeof(void*) + sizeof(uint32_t) * kTileVoxels);
}

}  // namespace nimbus
