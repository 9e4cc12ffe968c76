// Triangle meshes for sketch voxelisation: OBJ, PLY and STL readers and
// writers (docs/condensation.md). One file per format
// (mesh_obj.cc, mesh_ply.cc, mesh_stl.cc); mesh_io.cc dispatches.
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

/// A format to write (ASCII and binary are separate choices).
enum class MeshFormat { kObj, kPlyAscii, kPlyBinary, kStlAscii, kStlBinary };

/// A format to read as; ASCII or binary is told by the content.
enum class MeshFileType { kUnknown, kObj, kPly, kStl };

/// The type a file name or bare format word names, ignoring case:
/// "cow.obj", "x/Mesh.PLY", ".stl" and "stl" all name one; anything else
/// is kUnknown.
MeshFileType MeshFileTypeFromName(std::string_view name);

struct MeshLoadOptions {
  /// The format, for files whose name does not tell it (content-addressed
  /// assets have no extension). A PLY header always wins; kUnknown falls
  /// back to the path's extension, then to recognising STL by content.
  MeshFileType type = MeshFileType::kUnknown;
  /// What messages call the file, e.g. "cow.obj (sha256 3fa2c8...)";
  /// the path when empty.
  std::string display_name;
};

/// Reads an OBJ, PLY or STL file. The format comes from the file's content
/// (PLY header; STL by its "solid ... facet" opening or its binary size),
/// else from `options.type` or the path's extension. Errors name the file
/// (`options.display_name` or the path) and the line (text) or byte offset
/// (binary). The result has passed ValidateMesh.
absl::StatusOr<TriangleMesh> LoadMesh(const std::filesystem::path& path,
                                      const MeshLoadOptions& options);
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
