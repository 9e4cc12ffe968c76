// The block pool behind the chaos game's deferred writes: TileBins (32-bit
// entries, the affine fast path) and KeyBins (64-bit keys, the general
// path) keep their bins in one of these.
//
//   BinPool<uint32_t, walk::BinCursor> pool(bins, capacity, /*huge_pages=*/true);
//   // producers write *pool.cursors()[bin].tail++ until tail == end, then:
//   pool.Refill(bin, apply);  // apply(bin, begin, end) drains every bin when empty
//   pool.Drain(apply);        // at the end of a run
#pragma once

#include <sys/mman.h>

#include <algorithm>
#include <bit>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <memory>
#include <new>
#include <vector>

namespace nimbus {

/// @brief A fixed pool of equal blocks handed to bins on demand, each bin's
/// blocks chained in the order they filled. `Cursor` is a plain
/// `{Entry* tail; Entry* end;}`: the write position producers use. When
/// the pool is empty, Refill first drains every bin through the caller's
/// apply function and starts the pool over, so memory is fixed at
/// construction.
template <typename Entry, typename Cursor>
class BinPool {
 public:
  /// At most this many bins; larger grids put 2^TileShift tiles in a bin.
  static constexpr uint32_t kMaxBins = 32768;

  /// Tile-index bits dropped so that at most kMaxBins bins remain.
  static uint32_t TileShift(uint64_t tiles) {
    uint32_t shift = 0;
    while ((tiles >> shift) > kMaxBins) ++shift;
    return shift;
  }
  static uint64_t BinCount(uint64_t tiles) { return ((tiles - 1) >> TileShift(tiles)) + 1; }

  /// No pool (TileBins' direct mode).
  BinPool() = default;
  /// `bins` bins sharing room for `capacity` entries (at least one block).
  /// `huge_pages`: a pool of thousands of bins writes to as many pages at
  /// once, and 2 MiB pages spare the TLB (a hint; without THP it keeps
  /// 4 KiB pages).
  BinPool(size_t bins, size_t capacity, bool huge_pages)
      : block_(BlockSize(capacity, bins)),
        blocks_(uint32_t(std::max<size_t>(capacity / block_, 1))) {
    // Not value-initialised: pages are touched only as blocks fill.
    const size_t bytes = size_t(blocks_) * block_ * sizeof(Entry);
    constexpr size_t kHuge = size_t{2} << 20;
    const size_t rounded = (bytes + kHuge - 1) / kHuge * kHuge;
    pool_.reset(static_cast<Entry*>(huge_pages ? std::aligned_alloc(kHuge, rounded)
                                               : std::malloc(bytes)));
    if (!pool_) throw std::bad_alloc();
    if (huge_pages && rounded > kHuge) madvise(pool_.get(), rounded, MADV_HUGEPAGE);
    next_.assign(blocks_, -1);
    head_.assign(bins, -1);
    last_.assign(bins, -1);
    cursors_.resize(bins);
  }

  Cursor* cursors() { return cursors_.data(); }

  /// Gives `bin` a fresh block, draining every bin through `apply` first
  /// if the pool is empty.
  template <typename Apply>
  void Refill(uint32_t bin, Apply&& apply) {
    if (used_ == blocks_) Drain(apply);
    const int32_t block = int32_t(used_++);
    if (last_[bin] < 0)
      head_[bin] = block;
    else
      next_[last_[bin]] = block;
    last_[bin] = block;
    next_[block] = -1;
    Entry* begin = pool_.get() + size_t(block) * block_;
    cursors_[bin] = {begin, begin + block_};
  }

  /// Calls apply(bin, begin, end) for every filled range, bin by bin and
  /// in order within a bin, and empties the pool.
  template <typename Apply>
  void Drain(Apply&& apply) {
    DrainBins(0, bins(), apply);
    Reset();
  }
  /// Drain's work for bins [first, last) only: their ranges are applied
  /// and the bins left empty, but their blocks stay taken until Reset().
  template <typename Apply>
  void DrainBins(uint32_t first, uint32_t last, Apply&& apply) {
    for (uint32_t bin = first; bin < last; ++bin) {
      for (int32_t b = head_[bin]; b >= 0; b = next_[b]) {
        const Entry* begin = pool_.get() + size_t(b) * block_;
        apply(bin, begin, b == last_[bin] ? cursors_[bin].tail : begin + block_);
      }
      head_[bin] = last_[bin] = -1;
      cursors_[bin] = {};
    }
  }
  /// Makes every block free again; only after every bin was drained.
  void Reset() { used_ = 0; }
  /// True when the next Refill would have to drain first.
  bool exhausted() const { return used_ == blocks_; }
  uint32_t bins() const { return uint32_t(head_.size()); }

  /// Bytes held: the pool and the bookkeeping.
  uint64_t MemoryBytes() const {
    return uint64_t(blocks_) * block_ * sizeof(Entry) + next_.capacity() * sizeof(int32_t) +
           (head_.capacity() + last_.capacity()) * sizeof(int32_t) +
           cursors_.capacity() * sizeof(Cursor);
  }
  /// What MemoryBytes() will be for `bins` and `capacity`.
  static uint64_t Bytes(uint64_t bins, size_t capacity) {
    const uint32_t block = BlockSize(capacity, bins);
    const uint64_t blocks = std::max<uint64_t>(capacity / block, 1);
    return blocks * block * sizeof(Entry) + blocks * sizeof(int32_t) +
           bins * (2 * sizeof(int32_t) + sizeof(Cursor));
  }

 private:
  static uint32_t BlockSize(size_t capacity, size_t bins) {
    // About four blocks per bin when every bin is busy: small enough that a
    // thin fractal's few busy bins can take most of the pool, large enough
    // that block hand-outs are rare.
    const uint64_t per = std::max<uint64_t>(capacity / (4 * std::max<size_t>(bins, 1)), 1);
    return uint32_t(std::clamp<uint64_t>(std::bit_floor(per), 256, 4096));
  }

  struct Free {
    void operator()(Entry* p) const { std::free(p); }
  };
  uint32_t block_ = 0;   // entries per block
  uint32_t blocks_ = 0;  // blocks in the pool
  uint32_t used_ = 0;    // blocks handed out since the last drain
  std::unique_ptr<Entry[], Free> pool_;
  std::vector<int32_t> next_;         // per block: the bin's next block, or -1
  std::vector<int32_t> head_, last_;  // per bin: first and current block, or -1
  std::vector<Cursor> cursors_;
};

}  // namespace nimbus
