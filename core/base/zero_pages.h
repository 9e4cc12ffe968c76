// ZeroPages: zeroed memory mapped straight from the kernel.
//
//   ZeroPages words(n * sizeof(uint64_t), /*huge=*/true);
//   uint64_t* w = words.as<uint64_t>();  // all zero, nothing cleared
#pragma once

#include <cstddef>
#include <memory>
#include <utility>

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
  /// The bytes mapped: the size asked for, rounded up to whole pages
  /// (whole huge pages where huge ones were asked for, from 1 MiB on).
  size_t bytes() const { return bytes_; }
  explicit operator bool() const { return data_ != nullptr; }

  /// The mapping behind the class, for owners of their own: 2 MiB aligned,
  /// MappedBytes(bytes, huge) long; Unmap takes the same `bytes` and `huge`.
  /// A huge mapping of 1 MiB or more ends on a huge page too: the kernel
  /// backs only whole 2 MiB ranges of a mapping with huge pages, so a
  /// 1.5 MiB one would otherwise fault in 4 KiB at a time.
  static void* Map(size_t bytes, bool huge);
  /// Map(bytes, false) with every page mapped at once (MADV_POPULATE_WRITE,
  /// where the kernel has it): for a buffer about to be written in full,
  /// one call instead of a page fault per 4 KiB, some 12 us each on a
  /// virtual machine against under 1 us populated. Unmap with huge false.
  static void* MapPopulated(size_t bytes);
  /// Maps the pages of [data, data + bytes) of a mapping at once, as
  /// MapPopulated does (advice: nothing happens where it is refused).
  static void Populate(void* data, size_t bytes);
  static void Unmap(void* data, size_t bytes, bool huge);
  static size_t MappedBytes(size_t bytes, bool huge);

 private:
  void* data_ = nullptr;
  size_t bytes_ = 0;
};

/// @brief A std::vector allocator for large buffers that are written in
/// full before they are read (pictures' pixels): from kMinBytes on, memory
/// comes from ZeroPages::Map with huge pages, so a 12 MiB buffer takes six
/// page faults instead of three thousand (each costs microseconds, more in
/// a virtual machine), and the elements are left as they are (zero when
/// mapped, unspecified when smaller) instead of being cleared first:
/// `resize(n)` on such a vector costs no memset. Write every element.
/// From kPopulateBytes up to kMinBytes the pages are small but mapped in
/// one call (ZeroPages::MapPopulated), not faulted in one at a time.
template <class T>
struct ZeroPageAllocator {
  using value_type = T;
  static constexpr size_t kPopulateBytes = size_t{64} << 10;
  static constexpr size_t kMinBytes = size_t{1} << 20;

  ZeroPageAllocator() = default;
  template <class U>
  ZeroPageAllocator(const ZeroPageAllocator<U>&) {}

  T* allocate(size_t n) {
    const size_t bytes = n * sizeof(T);
    if (bytes < kPopulateBytes) return std::allocator<T>().allocate(n);
    if (bytes < kMinBytes) return static_cast<T*>(ZeroPages::MapPopulated(bytes));
    return static_cast<T*>(ZeroPages::Map(bytes, /*huge=*/true));
  }
  void deallocate(T* p, size_t n) {
    const size_t bytes = n * sizeof(T);
    if (bytes < kPopulateBytes) return std::allocator<T>().deallocate(p, n);
    ZeroPages::Unmap(p, bytes, /*huge=*/bytes >= kMinBytes);
  }
  /// Default initialisation: no value written (see above).
  template <class U>
  void construct(U* p) {
    ::new (static_cast<void*>(p)) U;
  }
  template <class U, class... Args>
  void construct(U* p, Args&&... args) {
    ::new (static_cast<void*>(p)) U(std::forward<Args>(args)...);
  }
  template <class U>
  bool operator==(const ZeroPageAllocator<U>&) const {
    return true;
  }
};

}  // namespace nimbus
