#include "core/io/leaf_runs.h"

#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <stdexcept>
#include <utility>

namespace nimbus::vdb_internal {

namespace {

thread_local const SpillScope* g_spill = nullptr;

// Throws the failure `what` of the spill file in `dir` with its errno `error`.
[[noreturn]] void SpillError(const char* what, int error, const std::filesystem::path& dir) {
  throw SpillFileError(std::string("leaf spill file: ") + what, error, dir);
}

// An unnamed file in `dir` (O_TMPFILE), or a named one removed at once where
// the file system lacks O_TMPFILE: either way nothing is left behind.
int OpenSpill(const std::filesystem::path& dir) {
  int fd = ::open(dir.c_str(), O_TMPFILE | O_RDWR | O_CLOEXEC, 0600);
  if (fd >= 0) return fd;
  std::string name = (dir / "leaves.spill.XXXXXX").string();
  fd = ::mkostemp(name.data(), O_CLOEXEC);
  if (fd < 0) SpillError("cannot create", errno, dir);
  ::unlink(name.c_str());
  return fd;
}

}  // namespace

SpillScope::SpillScope(std::filesystem::path dir, uint64_t keep_bytes)
    : outer_(g_spill), dir_(std::move(dir)), keep_bytes_(keep_bytes) {
  g_spill = this;
}
SpillScope::~SpillScope() { g_spill = outer_; }
const SpillScope* SpillScope::Current() { return g_spill; }

LeafRuns::LeafRuns() = default;
LeafRuns::LeafRuns(LeafRuns&& other) noexcept
    : blocks_(std::move(other.blocks_)), last_used_(other.last_used_),
      fd_(std::exchange(other.fd_, -1)), bytes_(other.bytes_), kept_(other.kept_) {}
LeafRuns::~LeafRuns() {
  if (fd_ >= 0) ::close(fd_);
}

void LeafRuns::Append(std::string_view run) {
  bytes_ += run.size();
  const SpillScope* spill = SpillScope::Current();
  if (fd_ < 0 && (spill == nullptr || kept_ + run.size() <= spill->keep_bytes())) {
    kept_ += run.size();
    return Keep(run);
  }
  if (fd_ < 0) fd_ = OpenSpill(spill->dir());
  for (size_t done = 0; done < run.size();) {
    const ssize_t n = ::write(fd_, run.data() + done, run.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) SpillError("write failed", n < 0 ? errno : ENOSPC, spill->dir());
    done += size_t(n);
  }
}

void LeafRuns::Keep(std::string_view run) {
  // A small first block keeps small grids small; later ones are 4 MiB
  // (two huge pages).
  constexpr size_t kFirst = size_t{256} << 10, kLater = size_t{4} << 20;
  constexpr size_t kPopulateFrom = size_t{16} << 10;
  while (!run.empty()) {
    if (blocks_.empty() || last_used_ == blocks_.back().bytes()) {
      blocks_.emplace_back(blocks_.empty() ? kFirst : kLater, /*huge=*/!blocks_.empty());
      last_used_ = 0;
    }
    const size_t n = std::min(run.size(), blocks_.back().bytes() - last_used_);
    // The small first block's pages in one call rather than a fault each
    // (the later ones are huge pages).
    if (blocks_.size() == 1 && n >= kPopulateFrom)
      ZeroPages::Populate(blocks_.back().as<char>() + last_used_, n);
    std::memcpy(blocks_.back().as<char>() + last_used_, run.data(), n);
    last_used_ += n;
    run.remove_prefix(n);
  }
}

void LeafRuns::WriteTo(std::ostream& os) const {
  for (size_t i = 0; i < blocks_.size(); ++i) {
    const size_t n = i + 1 < blocks_.size() ? blocks_[i].bytes() : last_used_;
    os.write(blocks_[i].as<char>(), std::streamsize(n));
  }
  if (fd_ < 0) return;
  // One huge page, faulted in once (the 1 MiB zero-filled string it
  // replaces took 256 faults).
  const ZeroPages buf(ZeroPages::kHugePage, /*huge=*/true);
  for (uint64_t at = 0; at < bytes_ - kept_;) {
    const ssize_t n = ::pread(fd_, buf.as<char>(), buf.bytes(), off_t(at));
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) SpillError("read failed", n < 0 ? errno : EIO, {});
    os.write(buf.as<char>(), n);
    at += uint64_t(n);
  }
}

}  // namespace nimbus::vdb_internal
