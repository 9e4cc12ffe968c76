// The format-independent part of mesh I/O: mesh measures, validation, and
// choosing a reader or writer. The formats live in mesh_{obj,ply,stl}.cc.
#include "core/io/mesh_io.h"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <sstream>

#include "absl/strings/ascii.h"
#include "core/io/mesh_io_internal.h"

namespace nimbus {

using namespace mesh_internal;  // NOLINT: shared helpers of the mesh files

Bounds TriangleMesh::GetBounds() const {
  if (vertices.empty()) return {};
  Bounds b{vertices[0], vertices[0]};
  for (const Vec3& v : vertices) {
    for (int a = 0; a < 3; ++a) {
      b.min[a] = std::min(b.min[a], v[a]);
      b.max[a] = std::max(b.max[a], v[a]);
    }
  }
  return b;
}

double TriangleMesh::SurfaceArea() const {
  double area = 0;
  for (const auto& t : triangles) {
    const Vec3 a = vertices[t[0]], b = vertices[t[1]], c = vertices[t[2]];
    area += 0.5 * Length(Cross(b - a, c - a));
  }
  return area;
}

absl::Status ValidateMesh(const TriangleMesh& mesh, std::string_view name) {
  if (mesh.triangles.empty() || mesh.vertices.empty())
    return absl::InvalidArgumentError(Cat(name, ": mesh is empty (no triangles)"));
  for (size_t i = 0; i < mesh.vertices.size(); ++i) {
    if (!IsFinite(mesh.vertices[i]))
      return absl::InvalidArgumentError(Cat(name, ": vertex ", i, " has a non-finite coordinate"));
  }
  const Bounds b = mesh.GetBounds();
  const double scale = std::max({b.Size().x, b.Size().y, b.Size().z});
  bool any_area = false;
  for (size_t i = 0; i < mesh.triangles.size(); ++i) {
    const auto& t = mesh.triangles[i];
    for (uint32_t v : t) {
      if (v >= mesh.vertices.size())
        return absl::InvalidArgumentError(
            Cat(name, ": triangle ", i, " uses vertex ", v, " of ", mesh.vertices.size()));
    }
    const Vec3 a = mesh.vertices[t[0]];
    const double twice_area = Length(Cross(mesh.vertices[t[1]] - a, mesh.vertices[t[2]] - a));
    // Relative to the mesh size, so that tiny but valid models pass.
    if (twice_area > 1e-14 * scale * scale) any_area = true;
  }
  if (!any_area) {
    return absl::InvalidArgumentError(Cat(name, ": mesh is degenerate: all ", mesh.triangles.size(),
                                          " triangles have zero area"));
  }
  return absl::OkStatus();
}

MeshFileType MeshFileTypeFromName(std::string_view name) {
  // A bare word ("obj") or an extension (".obj", "cow.obj").
  const size_t dot = name.rfind('.');
  std::string ext(dot == std::string_view::npos ? name : name.substr(dot + 1));
  if (ext.find('/') != std::string::npos || ext.find('\\') != std::string::npos) return {};
  absl::AsciiStrToLower(&ext);
  if (ext == "obj") return MeshFileType::kObj;
  if (ext == "ply") return MeshFileType::kPly;
  if (ext == "stl") return MeshFileType::kStl;
  return MeshFileType::kUnknown;
}

namespace {

// Which reader a file's bytes go to. PLY announces itself; STL is
// recognised by content only where the name does not say otherwise, so an
// OBJ stays an OBJ.
MeshFileType ChooseReader(std::string_view data, MeshFileType named) {
  if (data.starts_with("ply\n") || data.starts_with("ply\r\n")) return MeshFileType::kPly;
  if ((named == MeshFileType::kUnknown || named == MeshFileType::kStl) && LooksLikeStl(data))
    return MeshFileType::kStl;
  return named;
}

}  // namespace

absl::StatusOr<TriangleMesh> LoadMesh(const std::filesystem::path& path,
                                      const MeshLoadOptions& options) {
  const std::string name = options.display_name.empty() ? path.string() : options.display_name;
  std::ifstream in(path, std::ios::binary);
  if (!in) return absl::NotFoundError(Cat(name, ": cannot open mesh file"));
  std::ostringstream buf;
  buf << in.rdbuf();
  const std::string data = std::move(buf).str();
  // Only a name with a dot names a type: a bare "obj" file is not an OBJ.
  const MeshFileType from_path = path.has_extension()
                                     ? MeshFileTypeFromName(path.extension().string())
                                     : MeshFileType::kUnknown;
  const MeshFileType named = options.type != MeshFileType::kUnknown ? options.type : from_path;

  absl::StatusOr<TriangleMesh> mesh;
  switch (ChooseReader(data, named)) {
    case MeshFileType::kPly:
      mesh = ParsePly(data, name);  // reports a missing magic
      break;
    case MeshFileType::kStl:
      mesh = ParseStl(data, name);
      break;
    case MeshFileType::kObj:
      mesh = ParseObj(data, name);
      break;
    case MeshFileType::kUnknown:
      return absl::InvalidArgumentError(
          Cat(name, ": unknown mesh format (expected .obj, .ply or .stl)"));
  }
  if (!mesh.ok()) return mesh.status();
  if (absl::Status s = ValidateMesh(*mesh, name); !s.ok()) return s;
  return mesh;
}

absl::StatusOr<TriangleMesh> LoadMesh(const std::filesystem::path& path) {
  return LoadMesh(path, MeshLoadOptions{});
}

std::string SerializeMesh(const TriangleMesh& mesh, MeshFormat format) {
  switch (format) {
    case MeshFormat::kObj:
      return SerializeObj(mesh);
    case MeshFormat::kPlyAscii:
      return SerializePly(mesh, /*binary=*/false);
    case MeshFormat::kPlyBinary:
      return SerializePly(mesh, /*binary=*/true);
    case MeshFormat::kStlAscii:
      return SerializeStl(mesh, /*binary=*/false);
    case MeshFormat::kStlBinary:
      return SerializeStl(mesh, /*binary=*/true);
  }
  return {};
}

absl::Status SaveMesh(const TriangleMesh& mesh, const std::filesystem::path& path,
                      MeshFormat format) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  if (!out) return absl::InternalError(Cat(path.string(), ": cannot open for writing"));
  const std::string data = SerializeMesh(mesh, format);
  out.write(data.data(), std::streamsize(data.size()));
  if (!out) return absl::InternalError(Cat(path.string(), ": write failed"));
  return absl::OkStatus();
}

}  // namespace nimbus
