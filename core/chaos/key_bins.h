// Deferred CountGrid keys binned by tile: the write side of the general
// (flame, chain, splatting, colour) chaos-game path.
#pragma once

#include <cstddef>
#include <cstdint>
#include <mutex>

#include "core/base/zero_pages.h"
#include "core/chaos/bin_pool.h"
#include "core/chaos/packed_adds.h"
#include "core/grid/count_grid.h"

namespace nimbus {

/// @brief Collects whole CountGrid keys (voxel, weight and colour bits) in
/// per-tile bins as they are produced and applies them bin by bin, so a
/// tile's counters and colour sums are pulled into L2 once per flush and
/// then take thousands of increments, with the tile pointers resolved once
/// per run of keys of one tile: no sorting pass. Keys live in blocks from a
/// fixed pool (BinPool, as TileBins' entries do); when the pool runs out every bin
/// is applied and the pool starts over. Counts and colour sums are integer
/// sums, so the order of application changes nothing.
///
/// A small grid with colour (Packs(): a picture of up to a megapixel) is
/// not binned: its keys go into a dense per-thread array of one 64-bit
/// word per voxel that holds the visit count (top 24 bits) and the colour
/// sum (low 40 bits) together, a round after they were prefetched
/// (AddLanes holds one call's keys, a round's, until the next). Binning buys
/// nothing there, since the whole grid is touched between flushes anyway,
/// and one word is one cache line per key where a counter and a separate
/// colour sum are two. The words are folded into the grid (and zeroed) on
/// Flush() and before any count could pass 24 bits; the sums are the same
/// integers, so the grid ends up bit for bit as the binned path leaves it.
/// Folds are rare (a few per run), so the threads of a run may share one
/// grid, each folding its words under a lock they share.
///
/// Not thread-safe: one per thread, each over its thread's CountGrid (or,
/// packed, over one grid with `fold_lock`).
class KeyBins {
 public:
  /// `capacity`: keys buffered before a flush (at least one block).
  /// `weighted`: keys may carry a weight (CountGrid::WithWeight).
  /// `fold_lock`: packed folds take it, for a grid shared between threads.
  KeyBins(CountGrid& grid, size_t capacity, bool weighted, std::mutex* fold_lock = nullptr);

  void Add(uint64_t key) {
    if (packed_) [[unlikely]]
      return AddPacked(key);
    const uint32_t bin = uint32_t((key & CountGrid::kVoxelMask) >> shift_);
    Cursor& c = pool_.cursors()[bin];
    if (c.tail == c.end) [[unlikely]]
      Refill(bin);
    *c.tail++ = key;
  }
  /// Adds key[i] for every set bit i of `lanes` (a plot round's landed
  /// lanes); returns how many. Out of line on purpose: in a small function
  /// the loop's state stays in registers, where inlined into the caller's
  /// round loop it went through the stack on every key.
  uint64_t AddLanes(const uint64_t* key, uint64_t lanes) { return AddLanes(key, &lanes, 1); }
  /// The same for a round of several words of lanes: key[64 w + i] for
  /// every set bit i of lanes[w], w < `words` (at most kMaxLaneWords). The
  /// packed words take the whole round's keys at once, so each key is
  /// requested a whole kernel round before it is added.
  uint64_t AddLanes(const uint64_t* key, const uint64_t* lanes, int words);
  static constexpr int kMaxLaneWords = packed::kHoldRoom / 64;
  /// Applies every buffered key to the grid.
  void Flush();
  /// A packed Flush spread over threads by tile, for threads sharing one
  /// grid: BeginFold() adds the held keys and returns the tiles with words
  /// to fold (bit t: tile t); the caller allocates those tiles in the grid,
  /// then calls FoldTileOf(t) with each tile on one thread at a time (no
  /// lock is taken), then EndFold().
  uint64_t BeginFold();
  void FoldTileOf(uint64_t tile) {
    if (touched_ >> tile & 1) FoldTile(tile);
  }
  void EndFold();

  /// Bytes held: the pool and the bookkeeping, or the packed words.
  uint64_t MemoryBytes() const;
  /// What MemoryBytes() will be for a grid of `resolution` and `capacity`.
  static uint64_t Bytes(Int3 resolution, size_t capacity, bool color);
  /// True when a grid of `resolution` (with colour or not) takes the
  /// packed words rather than bins.
  static bool Packs(Int3 resolution, bool color);
  bool packed() const { return bool(packed_); }
  /// The grid outgrew its tile limit (CountGrid::overflowed); packed, as
  /// seen at this thread's last fold, so a shared grid is read under its
  /// lock only.
  bool overflowed() const { return packed_ ? overflowed_ : grid_.overflowed(); }

 private:
  struct Cursor {
    uint64_t* tail = nullptr;
    uint64_t* end = nullptr;
  };
  using Pool = BinPool<uint64_t, Cursor>;
  // Gives `bin` a fresh block, flushing everything first if the pool is empty.
  void Refill(uint32_t bin);
  void Apply(const uint64_t* begin, const uint64_t* end);
  auto ApplyFn() {
    return [this](uint32_t, const uint64_t* begin, const uint64_t* end) { Apply(begin, end); };
  }

  // The packed words' fields: count above kCountShift, colour sum below.
  static constexpr int kCountShift = packed::kCountShift;
  // Adds allowed between folds: no count reaches 2^24, so no colour sum
  // (at most 65535 per add) reaches 2^40 and carries into the count.
  static constexpr uint64_t kFoldAfter = (uint64_t{1} << 24) - 1;
  // The largest add of one AddLanes call (kHoldRoom keys of weight 64).
  static constexpr uint64_t kMaxCallAdds = packed::kHoldRoom * CountGrid::kMaxWeight;
  void AddPacked(uint64_t key);
  uint64_t AddLanesPacked(const uint64_t* key, const uint64_t* lanes, int words);
  // Adds the keys held by the last AddLanesPacked.
  void ApplyHeld();
  // Adds every packed word to the grid's tiles and zeroes it.
  void Fold();
  void FoldTile(uint64_t tile);

  CountGrid& grid_;
  bool weighted_ = false;
  uint32_t shift_ = 15;  // key bits below the bin index
  Pool pool_;
  // Packed mode: a word per stored voxel, indexed by the key's voxel bits.
  ZeroPages packed_;
  std::mutex* fold_lock_ = nullptr;
  bool overflowed_ = false;
  uint64_t pending_ = 0;  // adds since the last fold
  uint64_t touched_ = 0;  // bit t: tile t has words to fold (Packs: <= 64 tiles)
  // The last AddLanes call's keys, prefetched but not yet added (held_[flip_]).
  alignas(64) uint64_t held_[2][packed::kHoldRoom];
  const packed::Loops* loops_ = &packed::LoopsFor(SimdLevel::kScalar);
  uint32_t flip_ = 0, held_count_ = 0;
};

}  // namespace nimbus
