// One CountGrid filled by several threads' TileBins at once: the locks that
// keep their flushes apart.
#pragma once

#include <atomic>
#include <cstdint>
#include <memory>
#include <mutex>

#include "core/grid/count_grid.h"

namespace nimbus {

/// @brief Lets the threads of a binned chaos game share one CountGrid
/// instead of owning one each: the attractor's tiles are then cleared by
/// the kernel once, not once per thread, and there is nothing to merge.
/// The bins (TileBins' index space) are cut into kRanges runs of
/// consecutive bins, each behind a lock; a thread applies its bins range
/// by range holding that range's lock, so no tile is written by two
/// threads at once. Counts are sums, so the order in which the threads'
/// increments land changes nothing.
///
/// There is no barrier: each thread flushes when its own pool is full,
/// starting at a range of its own and taking free ranges first, so two
/// threads flushing together rarely wait for each other.
class SharedTiles {
 public:
  static constexpr uint32_t kRanges = 64;

  /// `bins`: the bin count of the TileBins that share `grid`.
  SharedTiles(CountGrid& grid, uint32_t bins);

  /// Calls f(first_bin, last_bin) once for each range, holding its lock,
  /// beginning with range `start` (mod kRanges).
  template <typename F>
  void ForEachRange(uint32_t start, F&& f) {
    uint64_t left = ~uint64_t{0};  // kRanges == 64 bits
    while (left) {
      bool progress = false;
      for (uint32_t i = 0; i < kRanges; ++i) {
        const uint32_t r = (start + i) % kRanges;
        if (!(left >> r & 1) || !locks_[r].try_lock()) continue;
        RunLocked(r, f);
        left &= ~(uint64_t{1} << r);
        progress = true;
      }
      if (progress || !left) continue;
      // Every range left is busy: wait for the first instead of spinning.
      const uint32_t r = uint32_t(__builtin_ctzll(left));
      locks_[r].lock();
      RunLocked(r, f);
      left &= ~(uint64_t{1} << r);
    }
  }

  /// Tile t's counters, allocated if need be; null past the grid's tile
  /// limit (overflowed() then turns true). Only while holding the lock of
  /// the range of t's bin.
  uint32_t* Tile(uint64_t t);

  /// The grid outgrew its tile limit: the run must stop.
  bool overflowed() const { return overflowed_.load(std::memory_order_relaxed); }

  /// Bins [RangeBegin(r), RangeBegin(r + 1)) form range r.
  uint32_t RangeBegin(uint32_t r) const { return uint32_t(uint64_t(bins_) * r / kRanges); }

 private:
  template <typename F>
  void RunLocked(uint32_t r, F& f) {
    std::lock_guard<std::mutex> hold(locks_[r], std::adopt_lock);
    f(RangeBegin(r), RangeBegin(r + 1));
  }

  CountGrid& grid_;
  uint32_t bins_;
  std::unique_ptr<std::mutex[]> locks_;
  std::mutex alloc_;  // the grid's allocator and tile count
  std::atomic<bool> overflowed_{false};
};

}  // namespace nimbus
