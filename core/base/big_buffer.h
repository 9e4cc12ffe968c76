/// @file big_buffer.h
/// @brief An allocator for large scratch arrays that the caller overwrites
/// in full: no zero fill, and transparent huge pages requested.
///
/// A 64 MiB `std::vector<uint32_t>::resize` costs about 400 ms on a
/// virtual machine where every 4 KiB page fault is slow, all of it on one
/// thread and before the first cancellation poll. With this allocator the
/// pages are faulted in 2 MiB at a time by the threads that first write
/// them.
///
///   std::vector<uint32_t, BigBufferAllocator<uint32_t>> field;
///   field.resize(n);  // contents unspecified until written
#pragma once

#include <sys/mman.h>

#include <cstddef>
#include <cstdlib>
#include <new>
#include <type_traits>
#include <utility>

namespace nimbus {

template <class T>
class BigBufferAllocator {
  static_assert(std::is_trivially_default_constructible_v<T>,
                "contents are left unset, so T must not need construction");

 public:
  using value_type = T;
  /// One transparent huge page: smaller buffers come from operator new.
  static constexpr size_t kHuge = size_t{2} << 20;
  BigBufferAllocator() = default;
  template <class U>
  BigBufferAllocator(const BigBufferAllocator<U>&) noexcept {}

  T* allocate(size_t n) {
    const size_t bytes = n * sizeof(T);
    if (bytes < kHuge) return static_cast<T*>(::operator new(bytes));
    void* p = std::aligned_alloc(kHuge, (bytes + kHuge - 1) / kHuge * kHuge);
    if (!p) throw std::bad_alloc();
    madvise(p, bytes, MADV_HUGEPAGE);  // advice only: failure is harmless
    return static_cast<T*>(p);
  }
  void deallocate(T* p, size_t n) noexcept {
    if (n * sizeof(T) < kHuge) {
      ::operator delete(p);
    } else {
      std::free(p);
    }
  }
  // resize() default-initialises: no zero fill.
  template <class U, class... Args>
  void construct(U* p, Args&&... args) {
    if constexpr (sizeof...(Args) == 0) {
      ::new (static_cast<void*>(p)) U;
    } else {
      ::new (static_cast<void*>(p)) U(std::forward<Args>(args)...);
    }
  }
  friend bool operator==(const BigBufferAllocator&, const BigBufferAllocator&) { return true; }
};

}  // namespace nimbus
