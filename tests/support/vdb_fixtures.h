// Small real files for tests of the upload checks: bytes of a file, and a
// level-set sphere written by OpenVDB itself.
#pragma once

#include <filesystem>
#include <string>

namespace nimbus::testing {

/// The whole file as bytes (empty when it cannot be read).
std::string ReadFileBytes(const std::filesystem::path& path);

/// Writes a level-set sphere grid "surface" (radius 10, voxel 0.5) to
/// `scratch` with OpenVDB's own writer and returns the file's bytes.
std::string SphereVdbBytes(const std::filesystem::path& scratch);

}  // namespace nimbus::testing
