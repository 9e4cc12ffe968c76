// VDB bytes -> ReadVdbBytes, the in-process reader a grid asset reaches.
//
// The server's untrusted-file checker (server/untrusted_file.h) reads
// uploads in a sandboxed child and has no in-process entry point, so this
// target fuzzes the reader itself. OpenVDB's stream reader is not hardened:
// corrupt headers can ask for gigabytes, which is why the checker runs in a
// child with RLIMIT_AS. Here inputs are capped and the run uses
// -rss_limit_mb=2048 / -malloc_limit_mb=2048; an out-of-memory report from
// inside OpenVDB is expected, one from Nimbus's own code is a bug.
#include "core/io/vdb_io.h"
#include "tests/fuzz/fuzz_util.h"

namespace {
// Big enough for a small Nimbus grid with a few leaves.
constexpr size_t kMaxInputBytes = 64 * 1024;
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size > kMaxInputBytes) return -1;  // -1: keep out of the corpus
  const std::string bytes(nimbus::fuzz::AsView(data, size));
  auto volume = nimbus::ReadVdbBytes(bytes, "density");
  if (volume.ok() && !volume->values.empty()) (void)volume->At(0, 0, 0);
  return 0;
}
