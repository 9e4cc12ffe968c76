// STL, ASCII and binary. Every facet gets its own three vertices; normals
// are ignored when reading and recomputed when writing.
#include <cstring>

#include "core/io/mesh_io.h"
#include "core/io/mesh_io_internal.h"

namespace nimbus {

using namespace mesh_internal;  // NOLINT: this file's own helpers

namespace {

constexpr size_t kBinaryHeaderBytes = 84;  // 80-byte comment + triangle count
constexpr size_t kBinaryFacetBytes = 50;   // normal, 3 corners, attribute word

bool LooksLikeAsciiStl(std::string_view data) {
  const std::string_view head = Trim(data.substr(0, 512));
  if (!head.starts_with("solid")) return false;
  // Binary files may also begin with "solid"; ASCII ones soon say "facet"
  // (or "endsolid" when empty).
  const std::string_view window = data.substr(0, 1024);
  return window.find("facet") != std::string_view::npos ||
         window.find("endsolid") != std::string_view::npos;
}

absl::StatusOr<TriangleMesh> ParseAsciiStl(std::string_view text, std::string_view name) {
  TriangleMesh mesh;
  LineReader reader(text);
  std::string_view line;
  std::vector<uint32_t> poly;
  bool in_loop = false;
  while (reader.Next(line)) {
    const int ln = reader.line_number();
    const std::vector<std::string_view> tok = Tokens(line);
    if (tok.empty()) continue;
    if (tok[0] == "outer") {
      if (in_loop) return LineError(name, ln, "nested 'outer loop'");
      in_loop = true;
      poly.clear();
    } else if (tok[0] == "vertex") {
      if (!in_loop) return LineError(name, ln, "vertex outside 'outer loop'");
      Vec3 p;
      if (absl::Status st = ParseVertex(tok, name, ln, p); !st.ok()) return st;
      poly.push_back(uint32_t(mesh.vertices.size()));
      mesh.vertices.push_back(p);
    } else if (tok[0] == "endloop") {
      if (!in_loop) return LineError(name, ln, "'endloop' without 'outer loop'");
      if (poly.size() < 3) return LineError(name, ln, "facet with fewer than 3 vertices");
      AddPolygon(poly, mesh);
      in_loop = false;
    }
    // solid, facet normal, endfacet, endsolid carry nothing we need.
  }
  if (in_loop) return LineError(name, reader.line_number(), "file ends inside a facet");
  return mesh;
}

absl::StatusOr<TriangleMesh> ParseBinaryStl(std::string_view data, std::string_view name) {
  if (data.size() < kBinaryHeaderBytes) {
    return OffsetError(
        name, data.size(),
        Cat("truncated binary STL: ", data.size(), " bytes is shorter than the 84-byte header"));
  }
  uint32_t n;
  std::memcpy(&n, data.data() + 80, 4);
  const uint64_t need = kBinaryHeaderBytes + uint64_t(n) * kBinaryFacetBytes;
  if (data.size() < need) {
    const uint64_t whole = (data.size() - kBinaryHeaderBytes) / kBinaryFacetBytes;
    return OffsetError(name, kBinaryHeaderBytes + whole * kBinaryFacetBytes,
                       Cat("truncated binary STL: header declares ", n, " triangles (", need,
                           " bytes) but the file has ", data.size(), " bytes"));
  }
  TriangleMesh mesh;
  mesh.vertices.reserve(size_t(n) * 3);
  mesh.triangles.reserve(n);
  for (uint32_t t = 0; t < n; ++t) {
    const size_t base = kBinaryHeaderBytes + size_t(t) * kBinaryFacetBytes;
    float f[9];
    std::memcpy(f, data.data() + base + 12, sizeof(f));  // skip the normal
    for (int k = 0; k < 3; ++k) {
      const Vec3 p{f[3 * k], f[3 * k + 1], f[3 * k + 2]};
      if (!IsFinite(p)) {
        return OffsetError(name, base + 12 + 12 * k, Cat("non-finite vertex in triangle ", t));
      }
      mesh.vertices.push_back(p);
    }
    mesh.triangles.push_back({3 * t, 3 * t + 1, 3 * t + 2});
  }
  return mesh;
}

Vec3 FaceNormal(const TriangleMesh& m, const std::array<uint32_t, 3>& t) {
  const Vec3 a = m.vertices[t[0]];
  const Vec3 n = Cross(m.vertices[t[1]] - a, m.vertices[t[2]] - a);
  const double len = Length(n);
  return len > 0 ? (1.0 / len) * n : Vec3{};
}

std::string SerializeAsciiStl(const TriangleMesh& mesh) {
  std::string out = "solid nimbus\n";
  for (const auto& t : mesh.triangles) {
    const Vec3 n = FaceNormal(mesh, t);
    AppendF(out, "  facet normal %.9g %.9g %.9g\n    outer loop\n", n.x, n.y, n.z);
    for (uint32_t i : t) {
      const Vec3 v = mesh.vertices[i];
      AppendF(out, "      vertex %.9g %.9g %.9g\n", float(v.x), float(v.y), float(v.z));
    }
    out += "    endloop\n  endfacet\n";
  }
  out += "endsolid nimbus\n";
  return out;
}

std::string SerializeBinaryStl(const TriangleMesh& mesh) {
  std::string out(80, ' ');
  out.replace(0, 14, "nimbus mesh   ");
  const uint32_t n = uint32_t(mesh.triangles.size());
  AppendRaw(out, &n, 4);
  for (const auto& t : mesh.triangles) {
    const Vec3 nn = FaceNormal(mesh, t);
    float f[12] = {float(nn.x), float(nn.y), float(nn.z)};
    for (int k = 0; k < 3; ++k)
      for (int a = 0; a < 3; ++a) f[3 + 3 * k + a] = float(mesh.vertices[t[k]][a]);
    AppendRaw(out, f, sizeof(f));
    const uint16_t attr = 0;
    AppendRaw(out, &attr, 2);
  }
  return out;
}

}  // namespace

absl::StatusOr<TriangleMesh> ParseStl(std::string_view data, std::string_view name) {
  if (LooksLikeAsciiStl(data)) return ParseAsciiStl(data, name);
  return ParseBinaryStl(data, name);
}

namespace mesh_internal {

bool LooksLikeStl(std::string_view data) {
  if (LooksLikeAsciiStl(data)) return true;
  if (data.size() < kBinaryHeaderBytes) return false;
  uint32_t n;
  std::memcpy(&n, data.data() + 80, 4);
  // Binary STL has no magic, but its size is fixed by the triangle count.
  return n > 0 && data.size() == kBinaryHeaderBytes + uint64_t(n) * kBinaryFacetBytes;
}

std::string SerializeStl(const TriangleMesh& mesh, bool binary) {
  return binary ? SerializeBinaryStl(mesh) : SerializeAsciiStl(mesh);
}

}  // namespace mesh_internal
}  // namespace nimbus
