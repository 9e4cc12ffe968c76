// VDB bytes -> ReadVdbBytes, the in-process reader a grid asset reaches.
//
// The server's untrusted-file checker (server/untrusted_file.h) reads
// uploads in a sandboxed child and has no in-process entry point, so this
// target fuzzes the reader itself. OpenVDB's stream reader is not hardened:
// a corrupt buffer size makes it ask for terabytes. The checker's child
// lives under RLIMIT_AS, where such a request is a std::bad_alloc that the
// reader's caller catches; ASan's operator new would abort instead and end
// the run at the first such input, so this binary replaces operator new
// with one that throws above 512 MiB (heap checks still apply: it
// allocates with ASan's malloc).
#include <cstdlib>
#include <new>

#include "core/io/vdb_io.h"
#include "tests/fuzz/fuzz_util.h"

namespace {

// Big enough for a small Nimbus grid with a few leaves.
constexpr size_t kMaxInputBytes = 64 * 1024;
// A quarter of the checker child's 2 GiB address space, so that one
// zero-filled allocation plus ASan's shadow and quarantine stays under
// -rss_limit_mb=2048.
constexpr size_t kMaxAllocation = size_t{512} << 20;

void* Allocate(size_t n, size_t align) {
  if (n > kMaxAllocation) return nullptr;
  if (n == 0) n = 1;
  void* p = nullptr;
  if (align <= alignof(std::max_align_t)) return std::malloc(n);
  return ::posix_memalign(&p, align, n) == 0 ? p : nullptr;
}

void* AllocateOrThrow(size_t n, size_t align) {
  if (void* p = Allocate(n, align)) return p;
  throw std::bad_alloc();
}

}  // namespace

// Every replaceable form, so none of ASan's aborting versions is linked.
void* operator new(size_t n) { return AllocateOrThrow(n, 0); }
void* operator new[](size_t n) { return AllocateOrThrow(n, 0); }
void* operator new(size_t n, std::align_val_t a) { return AllocateOrThrow(n, size_t(a)); }
void* operator new[](size_t n, std::align_val_t a) { return AllocateOrThrow(n, size_t(a)); }
void* operator new(size_t n, const std::nothrow_t&) noexcept { return Allocate(n, 0); }
void* operator new[](size_t n, const std::nothrow_t&) noexcept { return Allocate(n, 0); }
void* operator new(size_t n, std::align_val_t a, const std::nothrow_t&) noexcept {
  return Allocate(n, size_t(a));
}
void* operator new[](size_t n, std::align_val_t a, const std::nothrow_t&) noexcept {
  return Allocate(n, size_t(a));
}
void operator delete(void* p) noexcept { std::free(p); }
void operator delete[](void* p) noexcept { std::free(p); }
void operator delete(void* p, size_t) noexcept { std::free(p); }
void operator delete[](void* p, size_t) noexcept { std::free(p); }
void operator delete(void* p, std::align_val_t) noexcept { std::free(p); }
void operator delete[](void* p, std::align_val_t) noexcept { std::free(p); }
void operator delete(void* p, size_t, std::align_val_t) noexcept { std::free(p); }
void operator delete[](void* p, size_t, std::align_val_t) noexcept { std::free(p); }
void operator delete(void* p, const std::nothrow_t&) noexcept { std::free(p); }
void operator delete[](void* p, const std::nothrow_t&) noexcept { std::free(p); }
void operator delete(void* p, std::align_val_t, const std::nothrow_t&) noexcept { std::free(p); }
void operator delete[](void* p, std::align_val_t, const std::nothrow_t&) noexcept { std::free(p); }

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size > kMaxInputBytes) return -1;  // -1: keep out of the corpus
  const std::string bytes(nimbus::fuzz::AsView(data, size));
  auto volume = nimbus::ReadVdbBytes(bytes, "density");
  if (volume.ok() && !volume->values.empty()) (void)volume->At(0, 0, 0);
  return 0;
}
