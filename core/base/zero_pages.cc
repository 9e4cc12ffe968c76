#include "core/base/zero_pages.h"

#include <sys/mman.h>
#include <unistd.h>

#include <cstdint>
#include <new>
#include <utility>

namespace nimbus {

namespace {
size_t WholePages(size_t bytes) {
  const size_t page = size_t(sysconf(_SC_PAGESIZE));
  return (bytes + page - 1) / page * page;
}
}  // namespace

size_t ZeroPages::MappedBytes(size_t bytes, bool huge) {
  // Below half a huge page, rounding up would more than double the memory.
  if (!huge || bytes < kHugePage / 2) return WholePages(bytes);
  return (bytes + kHugePage - 1) / kHugePage * kHugePage;
}

void* ZeroPages::Map(size_t bytes, bool huge) {
  // Whole pages, so that the tail trimmed off below starts on a page.
  bytes = MappedBytes(bytes, huge);
  // Map a huge page more than needed and keep an aligned range of it.
  void* p = mmap(nullptr, bytes + kHugePage, PROT_READ | PROT_WRITE,
                 MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
  if (p == MAP_FAILED) throw std::bad_alloc();
  const uintptr_t start = uintptr_t(p), end = start + bytes + kHugePage;
  const uintptr_t aligned = (start + kHugePage - 1) & ~uintptr_t(kHugePage - 1);
  if (aligned > start) munmap(p, aligned - start);
  if (end > aligned + bytes)
    munmap(reinterpret_cast<void*>(aligned + bytes), end - aligned - bytes);
  void* data = reinterpret_cast<void*>(aligned);
  if (huge) madvise(data, bytes, MADV_HUGEPAGE);  // a hint: failure is harmless
  return data;
}

void* ZeroPages::MapPopulated(size_t bytes) {
  void* data = Map(bytes, /*huge=*/false);
  Populate(data, MappedBytes(bytes, false));
  return data;
}

void ZeroPages::Populate(void* data, size_t bytes) {
#ifndef MADV_POPULATE_WRITE
  constexpr int MADV_POPULATE_WRITE = 23;  // Linux 5.14; older kernels refuse it
#endif
  if (bytes == 0) return;
  const size_t page = size_t(sysconf(_SC_PAGESIZE));
  const uintptr_t start = uintptr_t(data) & ~uintptr_t(page - 1);
  const uintptr_t end = uintptr_t(data) + bytes;
  // Advice: where it is refused, the pages fault in as they are written.
  madvise(reinterpret_cast<void*>(start), end - start, MADV_POPULATE_WRITE);
}

void ZeroPages::Unmap(void* data, size_t bytes, bool huge) {
  if (data) munmap(data, MappedBytes(bytes, huge));
}

ZeroPages::ZeroPages(size_t bytes, bool huge)
    : data_(Map(bytes, huge)), bytes_(MappedBytes(bytes, huge)) {}

ZeroPages::ZeroPages(ZeroPages&& other) noexcept
    : data_(std::exchange(other.data_, nullptr)), bytes_(std::exchange(other.bytes_, 0)) {}

ZeroPages& ZeroPages::operator=(ZeroPages&& other) noexcept {
  std::swap(data_, other.data_);
  std::swap(bytes_, other.bytes_);
  return *this;
}

ZeroPages::~ZeroPages() { Unmap(data_, bytes_, /*huge=*/false); }  // bytes_ is whole already

}  // namespace nimbus
