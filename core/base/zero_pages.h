// ZeroPages: zeroed memory mapped straight from the kernel.
//
//   ZeroPages words(n * sizeof(uint64_t), /*huge=*/true);
//   uint64_t* w = words.as<uint64_t>();  // all zero, nothing cleared
#pragma once

#include <cstddef>

namespace nimbus {

/// @brief Anonymous pages from mmap: already zero, so a large array costs
/// no memset, and only the pages written take memory. The start is 2 MiB
/// aligned so that transparent huge pages can back the range; `huge` asks
/// for them (a hint: without THP the range keeps 4 KiB pages). Unmapped on
/// destruction; move-only.
class ZeroPages {
 public:
  static constexpr size_t kHugePage = size_t{2} << 20;

  ZeroPages() = default;
  /// Throws std::bad_alloc when the kernel has no memory.
  ZeroPages(size_t bytes, bool huge);
  ZeroPages(ZeroPages&& other) noexcept;
  ZeroPages& operator=(ZeroPages&& other) noexcept;
  ~ZeroPages();

  template <class T>
  T* as() const {
    return static_cast<T*>(data_);
  }
  /// The bytes mapped: the size asked for, rounded up to whole pages.
  size_t bytes() const { return bytes_; }
  explicit operator bool() const { return data_ != nullptr; }

 private:
  void* data_ = nullptr;
  size_t bytes_ = 0;
};

}  // namespace nimbus
