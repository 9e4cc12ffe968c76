// @brief What a result file means, as a digest: the oracle of golden checks
// and of scripts/example_digests.sh. Files are read back through their own
// libraries (OpenVDB's C++ API, libpng), never through Nimbus's readers, and
// hashed in a canonical order, so two writers of the same content give the
// same digest whatever their bytes.
#pragma once

#include <filesystem>
#include <string>

#include "absl/status/statusor.h"

namespace nimbus::testing {

/// @brief Hex SHA-256 of a .vdb file's content, read whole with OpenVDB:
/// its grids sorted by name, and per grid its name, value type, class,
/// vector type, index-to-world matrix, metadata (sorted by name, without
/// the `file_*` statistics the writer adds), background, every active
/// voxel and tile (origin, extent, value) in tree order, and every inactive
/// value that is not the background (a level set's inside). Not covered:
/// the UUID, half-float storage, compression, grid order in the file.
absl::StatusOr<std::string> VdbContentDigest(const std::filesystem::path& path);

/// Hex SHA-256 of a PNG's pixels read with libpng: width, height, bit
/// depth, channels, then every sample (16-bit ones big-endian).
absl::StatusOr<std::string> PngContentDigest(const std::filesystem::path& path);

/// The digest of any result file, by its first bytes: VdbContentDigest for
/// OpenVDB's magic, PngContentDigest for PNG's signature, else the SHA-256
/// of the bytes ("bytes:" prefixed), for text and other formats.
absl::StatusOr<std::string> ContentDigest(const std::filesystem::path& path);

}  // namespace nimbus::testing
