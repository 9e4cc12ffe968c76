// What `nimbus render -o OUT` names the files it downloads: each file's
// extension is its format's.
#pragma once

#include <filesystem>

#include "absl/status/statusor.h"
#include "nimbus/v1/spec.pb.h"

namespace nimbus::client {

/// Where the main result of a job running `spec` goes for `-o out`: `out`
/// itself when its extension is the result's format or it has none; `out`
/// with the result's extension when `out` names the picture the job writes
/// beside its volume (`-o x.png` on a volume job with a picture: x.vdb,
/// and the picture, a further file, is x.png next to it or in --frames).
/// INVALID_ARGUMENT naming -o when `out`'s
/// extension is another format's.
absl::StatusOr<std::filesystem::path> MainOutputPath(const std::filesystem::path& out,
                                                     const v1::JobSpec& spec);

/// OK when `out` has no extension or the extension of the downloaded file
/// `file_name` (a job's main or further file); INVALID_ARGUMENT naming -o
/// otherwise (`nimbus fetch`).
absl::Status CheckOutputExtension(const std::filesystem::path& out, const std::string& file_name);

}  // namespace nimbus::client
