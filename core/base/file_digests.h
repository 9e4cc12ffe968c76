// The SHA-256 of files this process has just written, recalled instead of
// read back:
//
//   RememberFileSha256(fd, sha);                    // the writer, file whole
//   ...
//   auto sha = RecallFileSha256(path);              // a commit, moments later
//   if (!sha) sha = Sha256File(path);               // anything else: hash it
#pragma once

#include <filesystem>
#include <optional>
#include <string>

namespace nimbus {

/// @brief Records `sha256` as the digest of the open file `fd` as it is now,
/// keyed by its identity: device, inode, size and modification time. A
/// rename keeps the entry; any later write or truncation misses. Keeps the
/// last few dozen files (a job's result and its side files).
void RememberFileSha256(int fd, const std::string& sha256);

/// @brief The remembered digest of `path`'s file if it is unchanged since,
/// else nothing (then hash it). Only for files this process wrote: a result
/// store verifying a file it did not write must hash it.
std::optional<std::string> RecallFileSha256(const std::filesystem::path& path);

}  // namespace nimbus
