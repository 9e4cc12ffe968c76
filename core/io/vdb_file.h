// Writing a .vdb file safely, with no OpenVDB: every write checked, the
// file fsynced, its UUID derived from its content, and renamed into place
// only when whole. Shared by the OpenVDB module's writers and the native
// result writer (vdb_native.h).
#pragma once

#include <cstdint>
#include <filesystem>
#include <functional>
#include <ostream>
#include <string>

#include "absl/status/status.h"

namespace nimbus::vdb_internal {

/// OpenVDB's file magic number (the first 8 bytes of every .vdb file).
inline constexpr int64_t kVdbMagic = 0x56444220;

/// Writes one archive to a seekable stream; may throw std::exception.
using ArchiveFn = std::function<void(std::ostream&)>;

/// Writes `path` + ".partial" with `write_archive`, checking every write,
/// fsyncs it, checks its size, stamps the content UUID and renames it into
/// place, so readers never see a half-written file. A full disk (ENOSPC,
/// EDQUOT) is RESOURCE_EXHAUSTED "disk full while writing the result: …";
/// other failures INTERNAL. Removes the partial file on failure.
absl::Status WriteArchiveAtomically(const std::filesystem::path& path,
                                    const ArchiveFn& write_archive);

/// Tests only: every later write fails with `error` (errno) once a file
/// would grow past `fail_after_bytes`; -1 turns the fault off. (The module
/// keeps its own copy: this one reaches the writers outside it.)
void SetWriteFaultForTesting(int64_t fail_after_bytes, int error);

/// OpenVDB writes a random UUID into every file; these replace it with one
/// derived from the SHA-256 of the rest of the file, so the same grids give
/// the same bytes. The UUID only tells readers whether two files are the
/// same, which a content hash says truthfully.
absl::Status StampContentUuid(const std::filesystem::path& path);
void StampContentUuid(std::string& bytes);

}  // namespace nimbus::vdb_internal
