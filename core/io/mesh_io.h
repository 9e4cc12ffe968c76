// Triangle meshes for sketch voxelisation: OBJ, PLY and STL readers and
// writers (ALGORITHMS.md section 1, "3D use").
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/base/geometry.h"

namespace nimbus {

/// @brief An indexed triangle mesh. Polygons with more than three corners
/// are fan-split into triangles when read.
struct TriangleMesh {
  std::vector<Vec3> vertices;
  std::vector<std::array<uint32_t, 3>> triangles;

  /// Box around all vertices (zero box for an empty mesh).
  Bounds GetBounds() const;
  /// Sum of triangle areas.
  double SurfaceArea() const;
};

enum class MeshFormat { kObj, kPlyAscii, kPlyBinary, kStlAscii, kStlBinary };

/// Reads an OBJ, PLY or STL file. The format comes from the file's content
/// (PLY header, STL size check) and, for OBJ, from the ".obj" extension.
/// Errors name the file and the line (text) or byte offset (binary).
/// The result has passed ValidateMesh.
absl::StatusOr<TriangleMesh> LoadMesh(const std::filesystem::path& path);

/// Parsers over in-memory file contents; `name` is used in error messages.
/// They check indices and finiteness but not degeneracy (see ValidateMesh).
absl::StatusOr<TriangleMesh> ParseObj(std::string_view text, std::string_view name);
absl::StatusOr<TriangleMesh> ParsePly(std::string_view data, std::string_view name);
absl::StatusOr<TriangleMesh> ParseStl(std::string_view data, std::string_view name);

/// Rejects meshes that cannot be voxelised: no triangles, a non-finite
/// vertex, an out-of-range index, or every triangle of zero area.
absl::Status ValidateMesh(const TriangleMesh& mesh, std::string_view name);

/// Serialises a mesh (little-endian for binary PLY/STL; STL stores floats).
std::string SerializeMesh(const TriangleMesh& mesh, MeshFormat format);
/// Writes SerializeMesh's output to `path`.
absl::Status SaveMesh(const TriangleMesh& mesh, const std::filesystem::path& path,
                      MeshFormat format);

}  // namespace nimbus
