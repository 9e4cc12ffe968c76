// A small real file for tests of the upload checks: a level-set sphere
// written by OpenVDB itself.
#pragma once

#include <filesystem>
#include <string>

namespace nimbus::testing {

/// Writes a level-set sphere grid "surface" (radius 10, voxel 0.5) to
/// `scratch` with OpenVDB's own writer and returns the file's bytes.
std::string SphereVdbBytes(const std::filesystem::path& scratch);

}  // namespace nimbus::testing
