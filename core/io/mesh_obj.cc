// Wavefront OBJ: only vertex positions and faces matter to the solid.
#include "absl/strings/str_cat.h"
#include "core/io/mesh_io.h"
#include "core/io/mesh_io_internal.h"

namespace nimbus {

using namespace mesh_internal;  // NOLINT: this file's own helpers

namespace {

// The 0-based vertex of one face corner ("v", "v/vt", "v//vn" or
// "v/vt/vn"), or an error naming the corner.
absl::StatusOr<uint32_t> FaceCorner(std::string_view corner, size_t vertex_count,
                                    std::string_view name, int ln) {
  const std::string_view ref = corner.substr(0, corner.find('/'));
  int64_t idx;
  if (!ParseInt(ref, idx) || idx == 0)
    return LineError(name, ln, Cat("bad face index '", corner, "'"));
  // OBJ indices are 1-based; negative ones count back from the last vertex.
  const int64_t n = int64_t(vertex_count);
  const int64_t resolved = idx > 0 ? idx - 1 : n + idx;
  if (resolved < 0 || resolved >= n) {
    return LineError(name, ln,
                     Cat("face index ", idx, " out of range (", n, " vertices defined so far)"));
  }
  return uint32_t(resolved);
}

}  // namespace

absl::StatusOr<TriangleMesh> ParseObj(std::string_view text, std::string_view name) {
  TriangleMesh mesh;
  LineReader reader(text);
  std::string_view line;
  std::vector<uint32_t> poly;
  while (reader.Next(line)) {
    const int ln = reader.line_number();
    if (const size_t hash = line.find('#'); hash != std::string_view::npos)
      line = line.substr(0, hash);
    const std::vector<std::string_view> tok = Tokens(line);
    if (tok.empty()) continue;
    if (tok[0] == "v") {
      Vec3 p;
      if (absl::Status st = ParseVertex(tok, name, ln, p); !st.ok()) return st;
      mesh.vertices.push_back(p);
    } else if (tok[0] == "f") {
      if (tok.size() < 4) return LineError(name, ln, "face needs at least three corners");
      if (tok.size() - 1 > kMaxPolygonCorners)
        return LineError(name, ln, TooManyCorners(tok.size() - 1));
      poly.clear();
      for (size_t k = 1; k < tok.size(); ++k) {
        absl::StatusOr<uint32_t> v = FaceCorner(tok[k], mesh.vertices.size(), name, ln);
        if (!v.ok()) return v.status();
        poly.push_back(*v);
      }
      AddPolygon(poly, mesh);
    }
    // vt, vn, g, o, s, usemtl, mtllib, l, p: irrelevant to the solid.
  }
  return mesh;
}

namespace mesh_internal {

std::string SerializeObj(const TriangleMesh& mesh) {
  std::string out;
  for (const Vec3& v : mesh.vertices) AppendF(out, "v %.17g %.17g %.17g\n", v.x, v.y, v.z);
  for (const auto& t : mesh.triangles)
    absl::StrAppend(&out, "f ", t[0] + 1, " ", t[1] + 1, " ", t[2] + 1, "\n");
  return out;
}

}  // namespace mesh_internal
}  // namespace nimbus
