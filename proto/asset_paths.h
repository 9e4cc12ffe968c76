// Where a spec's assets are: every Asset message of a spec (mesh and grid
// sources at any depth), relative paths made absolute, and an uploaded
// asset found by its hash. The client uses this without the converters.
#pragma once

#include <filesystem>
#include <functional>
#include <string>

#include "absl/status/statusor.h"
#include "nimbus/v1/spec.pb.h"

namespace nimbus::spec {

/// Where a stored asset lives: `dir`/<sha256><ext>. NOT_FOUND names the
/// hash when no upload has it.
absl::StatusOr<std::filesystem::path> FindStoredAsset(const std::filesystem::path& dir,
                                                      const std::string& sha256);

/// Calls `f(path_field, asset)` for every Asset message of the spec (mesh
/// and grid sources, at any depth), so clients can upload and rewrite them.
void ForEachAsset(v1::JobSpec& spec,
                  const std::function<void(const std::string& field, v1::Asset& asset)>& f);

/// Makes relative asset paths absolute against `base_dir` (the spec file's
/// folder), as the CLI does before uploading.
void ResolveAssetPaths(v1::JobSpec& spec, const std::filesystem::path& base_dir);

}  // namespace nimbus::spec
