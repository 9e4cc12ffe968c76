#include "core/chaos/key_bins.h"

#include <bit>

namespace nimbus {

namespace {

// Applies a run of keys of one tile; returns where the run ends. The
// variants keep the common cases (plain counts; counts and colour) free of
// the weight and colour arithmetic they do not need.
constexpr int kAhead = 64;

template <bool kColor, bool kWeighted>
const uint64_t* ApplyTile(CountGrid& grid, const uint64_t* e, const uint64_t* end) {
  const uint64_t tile = (*e & CountGrid::kVoxelMask) >> 15;
  uint32_t* counts = grid.MutableTile(tile);
  uint64_t* colors = kColor ? grid.MutableColorTile(tile) : nullptr;
  for (; e != end && ((*e & CountGrid::kVoxelMask) >> 15) == tile; ++e) {
    if (end - e > kAhead) {
      const uint32_t ahead = uint32_t(e[kAhead] & 0x7fff);
      __builtin_prefetch(counts + ahead, 1);
      if constexpr (kColor) __builtin_prefetch(colors + ahead, 1);
    }
    const uint32_t off = uint32_t(*e & 0x7fff);
    const uint32_t add = kWeighted ? CountGrid::WeightOf(*e) : 1;
    counts[off] += add;
    if constexpr (kColor) colors[off] += uint64_t(add) * (*e >> CountGrid::kColorShift);
  }
  return e;
}

// At most this many tiles (8 MiB of words: a 1024 x 1024 picture) are
// packed; larger grids keep the bins, whose tile-at-a-time flushes then
// pay for themselves.
constexpr uint64_t kPackedTiles = 32;
template <bool kColor, bool kWeighted>
void ApplyAll(CountGrid& grid, const uint64_t* e, const uint64_t* end) {
  while (e != end) e = ApplyTile<kColor, kWeighted>(grid, e, end);
}

}  // namespace

bool KeyBins::Packs(Int3 resolution, bool color) {
  return color && CountGrid::TileCountFor(resolution) <= kPackedTiles;
}

KeyBins::KeyBins(CountGrid& grid, size_t capacity, bool weighted, std::mutex* fold_lock)
    : grid_(grid), weighted_(weighted), fold_lock_(fold_lock) {
  const uint64_t tiles = CountGrid::TileCountFor(grid.resolution());
  if (Packs(grid.resolution(), grid.has_color())) {
    const size_t bytes = size_t(tiles) * CountGrid::kTileVoxels * sizeof(uint64_t);
    // Huge pages: a few faults instead of one per 4 KiB.
    packed_ = ZeroPages(bytes, /*huge=*/true);
    loops_ = &packed::LoopsFor(ActiveSimd());
    // Folds write every tile the words touched, usually most of the grid's
    // few: its first 2 MiB in 4 KiB pages would cost a thousand faults.
    grid.PreferHugePages();
    return;
  }
  shift_ = 15 + Pool::TileShift(tiles);
  pool_ = Pool(size_t(Pool::BinCount(tiles)), capacity, /*huge_pages=*/false);
}

uint64_t KeyBins::AddLanes(const uint64_t* key, const uint64_t* lanes, int words) {
  if (packed_) return AddLanesPacked(key, lanes, words);
  uint64_t added = 0;
  // Bits walked one by one: the x86-64 baseline has no popcnt.
  for (int w = 0; w < words; ++w)
    for (uint64_t m = lanes[w]; m; m &= m - 1, ++added) Add(key[64 * w + std::countr_zero(m)]);
  return added;
}

uint64_t KeyBins::AddLanesPacked(const uint64_t* key, const uint64_t* lanes, int words) {
  if (pending_ > kFoldAfter - kMaxCallAdds) Fold();
  // This round's keys are only requested now and held; the previous
  // round's, requested a whole kernel round ago, are added: their words
  // are in L1 by then, where adding right after the request waited on
  // every miss. (Each word's keys land below 64 (w + 1): the hold loops'
  // whole-register stores stay inside the room.)
  uint64_t* hold = held_[flip_ ^ 1];
  uint32_t added = 0;
  for (int w = 0; w < words; ++w)
    added += loops_->hold(packed_.as<uint64_t>(), key + 64 * w, lanes[w], hold + added);
  uint64_t adds = added;
  if (weighted_) {
    adds = 0;
    for (uint32_t i = 0; i < added; ++i) adds += CountGrid::WeightOf(hold[i]);
  }
  ApplyHeld();
  flip_ ^= 1;
  held_count_ = added;
  pending_ += adds;  // counted when held: Fold applies the held keys first
  return added;
}

void KeyBins::ApplyHeld() {
  touched_ |= loops_->apply(packed_.as<uint64_t>(), held_[flip_], held_count_, weighted_);
  held_count_ = 0;
}

void KeyBins::AddPacked(uint64_t key) {
  if (pending_ > kFoldAfter - kMaxCallAdds) Fold();
  const uint64_t add = weighted_ ? CountGrid::WeightOf(key) : 1;
  const uint64_t voxel = key & CountGrid::kVoxelMask;
  packed_.as<uint64_t>()[voxel] += (add << kCountShift) + add * (key >> CountGrid::kColorShift);
  touched_ |= uint64_t{1} << (voxel >> 15);
  pending_ += add;
}

uint64_t KeyBins::BeginFold() {
  ApplyHeld();
  return touched_;
}

void KeyBins::EndFold() {
  overflowed_ = grid_.overflowed();
  touched_ = pending_ = 0;
}

void KeyBins::Fold() {
  ApplyHeld();
  if (touched_) {
    std::unique_lock<std::mutex> lock;
    if (fold_lock_) lock = std::unique_lock<std::mutex>(*fold_lock_);
    for (uint64_t m = touched_; m; m &= m - 1) FoldTile(uint64_t(std::countr_zero(m)));
    overflowed_ = grid_.overflowed();
  }
  touched_ = pending_ = 0;
}

void KeyBins::FoldTile(uint64_t tile) {
  constexpr uint64_t kColorMask = (uint64_t{1} << kCountShift) - 1;
  uint32_t* counts = grid_.MutableTile(tile);
  uint64_t* colors = grid_.MutableColorTile(tile);
  uint64_t* words = packed_.as<uint64_t>() + (tile << 15);
  // Counts saturate at 2^32 - 1, as CountGrid::Merge does, so a grid that
  // threads share holds min(visits, 2^32 - 1) whatever their number.
  for (int i = 0; i < CountGrid::kTileVoxels; ++i) {
    const uint64_t sum = counts[i] + (words[i] >> kCountShift);
    counts[i] = sum > UINT32_MAX ? UINT32_MAX : uint32_t(sum);
    colors[i] += words[i] & kColorMask;
    words[i] = 0;
  }
}

void KeyBins::Refill(uint32_t bin) { pool_.Refill(bin, ApplyFn()); }

void KeyBins::Apply(const uint64_t* begin, const uint64_t* end) {
  if (grid_.has_color())
    weighted_ ? ApplyAll<true, true>(grid_, begin, end) : ApplyAll<true, false>(grid_, begin, end);
  else
    weighted_ ? ApplyAll<false, true>(grid_, begin, end)
              : ApplyAll<false, false>(grid_, begin, end);
}

void KeyBins::Flush() {
  if (packed_) return Fold();
  pool_.Drain(ApplyFn());
}

uint64_t KeyBins::MemoryBytes() const {
  return packed_ ? packed_.bytes() : pool_.MemoryBytes();
}

uint64_t KeyBins::Bytes(Int3 resolution, size_t capacity, bool color) {
  const uint64_t tiles = CountGrid::TileCountFor(resolution);
  if (Packs(resolution, color)) return tiles * CountGrid::kTileVoxels * sizeof(uint64_t);
  return Pool::Bytes(Pool::BinCount(tiles), capacity);
}

}  // namespace nimbus
