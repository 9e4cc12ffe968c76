// Encoded leaf buffers of one grid, kept in memory up to a bound and past
// it spilled to an unnamed file: a writer needs every leaf's encoding
// before it writes the grid's header. No OpenVDB: shared by the module's
// streamed writer (vdb_stream.h) and the native one (vdb_native.h).
#pragma once

#include <cstdint>
#include <filesystem>
#include <ostream>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include "core/base/zero_pages.h"

namespace nimbus::vdb_internal {

/// What LeafRuns throws when its spill file fails. The message names no
/// folder (it may reach a client); `error` is the errno, so a writer can
/// tell a full disk from other failures, and `dir` the spill's folder
/// (empty when not known).
class SpillFileError : public std::runtime_error {
 public:
  SpillFileError(const std::string& what, int error, std::filesystem::path dir)
      : std::runtime_error(what), error_(error), dir_(std::move(dir)) {}
  int error() const { return error_; }
  const std::filesystem::path& dir() const { return dir_; }

 private:
  int error_;
  std::filesystem::path dir_;
};

/// @brief Every leaf's LeafNode::writeBuffers bytes of one grid, in tree
/// order, appended run by run. The archive needs them all before it can
/// write the grid's header (which records each leaf's encoded size), so a
/// large grid would hold its whole compressed size in memory: past
/// `keep_bytes`, runs go to an unnamed temporary file in the spill
/// directory that a SpillScope names on this thread (none: all in memory).
/// Kept runs are copied back to back into blocks mapped from the kernel,
/// past the first with huge pages: a fresh heap would fault them in 4 KiB
/// at a time (about 11 us each on a virtual machine, a thousand per 4 MiB).
class LeafRuns {
 public:
  LeafRuns();
  LeafRuns(LeafRuns&& other) noexcept;
  LeafRuns& operator=(LeafRuns&&) = delete;
  ~LeafRuns();
  /// Appends a copy of `run`. Throws SpillFileError when the spill file
  /// fails.
  void Append(std::string_view run);
  /// Writes every run to `os`, in order, through one bounded buffer.
  /// Throws SpillFileError when the spill file cannot be read back.
  void WriteTo(std::ostream& os) const;
  uint64_t bytes() const { return bytes_; }
  bool spilled() const { return fd_ >= 0; }

 private:
  void Keep(std::string_view run);

  std::vector<ZeroPages> blocks_;  // the kept runs' bytes, each block filled before the next
  size_t last_used_ = 0;           // bytes used in the last block
  int fd_ = -1;                    // the spill file, once past keep_bytes
  uint64_t bytes_ = 0, kept_ = 0;
};

/// Names, for this thread's EncodeLeaves calls while it lives, the
/// directory where grids past `keep_bytes` of encoded leaves spill (the
/// result's own directory: same disk, no RAM).
class SpillScope {
 public:
  SpillScope(std::filesystem::path dir, uint64_t keep_bytes);
  ~SpillScope();
  SpillScope(const SpillScope&) = delete;
  SpillScope& operator=(const SpillScope&) = delete;
  /// The innermost scope alive on this thread, or null.
  static const SpillScope* Current();
  const std::filesystem::path& dir() const { return dir_; }
  uint64_t keep_bytes() const { return keep_bytes_; }

 private:
  const SpillScope* outer_;
  std::filesystem::path dir_;
  uint64_t keep_bytes_;
};

/// Encoded bytes a grid keeps in memory before it spills (WriteStreamedAtomically).
inline constexpr uint64_t kSpillKeepBytes = uint64_t{4} << 20;

}  // namespace nimbus::vdb_internal
