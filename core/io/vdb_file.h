// Writing a .vdb file safely: every write checked, the file fsynced, its
// UUID derived from its content, and renamed into place only when whole.
// Part of the OpenVDB module (vdb_module.h), under every writer of it.
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
/// stamps the content UUID, fsyncs it (handing its SHA-256 to the digest
/// sink), checks its size and renames it into place, so readers never see a
/// half-written file. A full disk (ENOSPC, EDQUOT) is RESOURCE_EXHAUSTED
/// "disk full while writing the result: NAME: …"; other failures INTERNAL.
/// Messages name the file, never its folder. Removes the partial file on
/// failure.
absl::Status WriteArchiveAtomically(const std::filesystem::path& path,
                                    const ArchiveFn& write_archive);

/// Tests only: every later write fails with `error` (errno) once a file
/// would grow past `fail_after_bytes`; -1 turns the fault off.
void SetWriteFaultForTesting(int64_t fail_after_bytes, int error);

/// Where WriteArchiveAtomically records the digest of each file it wrote:
/// RememberFileSha256 (core/base/file_digests.h) of the program that
/// loaded the module, which LoadVdbModule installs, since the module holds
/// a copy of core/base of its own. Null restores the module's copy.
using DigestSink = void (*)(int fd, const std::string& sha256);
void SetDigestSink(DigestSink sink);

/// OpenVDB writes a random UUID into every file; these replace it with one
/// derived from the SHA-256 of the rest of the file, so the same grids give
/// the same bytes. The UUID only tells readers whether two files are the
/// same, which a content hash says truthfully. (WriteArchiveAtomically
/// derives it from the writes as they go out instead, its offsets with its
/// bytes: as deterministic, without reading the file again.)
absl::Status StampContentUuid(const std::filesystem::path& path);
void StampContentUuid(std::string& bytes);

}  // namespace nimbus::vdb_internal
