#include "core/io/mesh_io.h"

#include <algorithm>
#include <bit>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <optional>
#include <sstream>

#include "absl/strings/ascii.h"
#include "absl/strings/str_cat.h"

namespace nimbus {

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

namespace {

// ---------------------------------------------------------------- text helpers

// absl::string_view is not std::string_view in this abseil build, so error
// messages are assembled with a stream.
template <typename... Args>
std::string Cat(const Args&... args) {
  std::ostringstream os;
  os.precision(17);
  (os << ... << args);
  return os.str();
}

bool IsSpace(char c) {
  return c == ' ' || c == '\t' || c == '\f' || c == '\v' || c == '\r' || c == '\n';
}

std::string_view Trim(std::string_view s) {
  while (!s.empty() && IsSpace(s.front())) s.remove_prefix(1);
  while (!s.empty() && IsSpace(s.back())) s.remove_suffix(1);
  return s;
}

// Splits text into lines (LF or CRLF), tracking 1-based line numbers.
class LineReader {
 public:
  explicit LineReader(std::string_view text) : text_(text) {}
  bool Next(std::string_view& line) {
    if (pos_ >= text_.size()) return false;
    size_t end = text_.find('\n', pos_);
    if (end == std::string_view::npos) end = text_.size();
    line = text_.substr(pos_, end - pos_);
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    pos_ = end + 1;
    ++line_number_;
    return true;
  }
  int line_number() const { return line_number_; }
  size_t position() const { return pos_; }

 private:
  std::string_view text_;
  size_t pos_ = 0;
  int line_number_ = 0;
};

std::vector<std::string_view> Tokens(std::string_view line) {
  std::vector<std::string_view> out;
  size_t i = 0;
  while (i < line.size()) {
    while (i < line.size() && IsSpace(line[i])) ++i;
    const size_t start = i;
    while (i < line.size() && !IsSpace(line[i])) ++i;
    if (i > start) out.push_back(line.substr(start, i - start));
  }
  return out;
}

bool ParseDouble(std::string_view s, double& out) {
  if (!s.empty() && s.front() == '+') s.remove_prefix(1);
  const auto [ptr, ec] = std::from_chars(s.data(), s.data() + s.size(), out);
  return ec == std::errc() && ptr == s.data() + s.size();
}

bool ParseInt(std::string_view s, int64_t& out) {
  if (!s.empty() && s.front() == '+') s.remove_prefix(1);
  const auto [ptr, ec] = std::from_chars(s.data(), s.data() + s.size(), out);
  return ec == std::errc() && ptr == s.data() + s.size();
}

absl::Status LineError(std::string_view name, int line, std::string_view what) {
  return absl::InvalidArgumentError(Cat(name, ":", line, ": ", what));
}

absl::Status OffsetError(std::string_view name, size_t offset, std::string_view what) {
  return absl::InvalidArgumentError(Cat(name, ": byte offset ", offset, ": ", what));
}

// The three coordinates of an OBJ "v" or ASCII STL "vertex" line, tok[1..3].
absl::Status ParseVertex(const std::vector<std::string_view>& tok, std::string_view name, int ln,
                         Vec3& p) {
  if (tok.size() < 4) return LineError(name, ln, "vertex needs three coordinates");
  for (int a = 0; a < 3; ++a) {
    if (!ParseDouble(tok[1 + a], p[a]))
      return LineError(name, ln, Cat("bad vertex coordinate '", tok[1 + a], "'"));
  }
  if (!IsFinite(p)) return LineError(name, ln, "non-finite vertex coordinate");
  return absl::OkStatus();
}

// Fan-splits a polygon given by vertex indices.
void AddPolygon(const std::vector<uint32_t>& poly, TriangleMesh& mesh) {
  for (size_t k = 1; k + 1 < poly.size(); ++k)
    mesh.triangles.push_back({poly[0], poly[k], poly[k + 1]});
}

// ---------------------------------------------------------------- OBJ

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
      poly.clear();
      for (size_t k = 1; k < tok.size(); ++k) {
        // "v", "v/vt", "v//vn" or "v/vt/vn": only the position index matters.
        const std::string_view ref = tok[k].substr(0, tok[k].find('/'));
        int64_t idx;
        if (!ParseInt(ref, idx) || idx == 0)
          return LineError(name, ln, Cat("bad face index '", tok[k], "'"));
        // OBJ indices are 1-based; negative ones count back from the last vertex.
        const int64_t n = int64_t(mesh.vertices.size());
        const int64_t resolved = idx > 0 ? idx - 1 : n + idx;
        if (resolved < 0 || resolved >= n) {
          return LineError(
              name, ln, Cat("face index ", idx, " out of range (", n, " vertices defined so far)"));
        }
        poly.push_back(uint32_t(resolved));
      }
      AddPolygon(poly, mesh);
    }
    // vt, vn, g, o, s, usemtl, mtllib, l, p: irrelevant to the solid.
  }
  return mesh;
}

// ---------------------------------------------------------------- PLY

namespace {

enum class PlyType { kInt8, kUint8, kInt16, kUint16, kInt32, kUint32, kFloat32, kFloat64 };

bool ParsePlyType(std::string_view s, PlyType& t) {
  static const std::pair<std::string_view, PlyType> kNames[] = {
      {"char", PlyType::kInt8},      {"int8", PlyType::kInt8},       {"uchar", PlyType::kUint8},
      {"uint8", PlyType::kUint8},    {"short", PlyType::kInt16},     {"int16", PlyType::kInt16},
      {"ushort", PlyType::kUint16},  {"uint16", PlyType::kUint16},   {"int", PlyType::kInt32},
      {"int32", PlyType::kInt32},    {"uint", PlyType::kUint32},     {"uint32", PlyType::kUint32},
      {"float", PlyType::kFloat32},  {"float32", PlyType::kFloat32}, {"double", PlyType::kFloat64},
      {"float64", PlyType::kFloat64}};
  for (const auto& [n, type] : kNames) {
    if (s == n) {
      t = type;
      return true;
    }
  }
  return false;
}

int PlyTypeSize(PlyType t) {
  switch (t) {
    case PlyType::kInt8:
    case PlyType::kUint8:
      return 1;
    case PlyType::kInt16:
    case PlyType::kUint16:
      return 2;
    case PlyType::kInt32:
    case PlyType::kUint32:
    case PlyType::kFloat32:
      return 4;
    case PlyType::kFloat64:
      return 8;
  }
  return 0;
}

struct PlyProperty {
  std::string name;
  bool is_list = false;
  PlyType count_type = PlyType::kUint8;  // lists only
  PlyType type = PlyType::kFloat32;
};

struct PlyElement {
  std::string name;
  uint64_t count = 0;
  std::vector<PlyProperty> properties;
};

enum class PlyFormat { kAscii, kBinaryLittle, kBinaryBig };

// Sequential reader of binary PLY values with bounds checks.
class BinaryCursor {
 public:
  BinaryCursor(std::string_view data, size_t pos, bool big_endian)
      : data_(data), pos_(pos), big_endian_(big_endian) {}
  size_t position() const { return pos_; }
  bool Read(PlyType t, double& out) {
    const int n = PlyTypeSize(t);
    if (pos_ + n > data_.size()) return false;
    unsigned char b[8];
    std::memcpy(b, data_.data() + pos_, n);
    pos_ += n;
    // Values are stored in the file's byte order; this machine is little-endian.
    static_assert(std::endian::native == std::endian::little);
    if (big_endian_) std::reverse(b, b + n);
    // In PlyType order.
    static constexpr double (*kLoad[])(const unsigned char*) = {
        &Load<int8_t>,  &Load<uint8_t>,  &Load<int16_t>, &Load<uint16_t>,
        &Load<int32_t>, &Load<uint32_t>, &Load<float>,   &Load<double>};
    out = kLoad[int(t)](b);
    return true;
  }

 private:
  template <typename T>
  static double Load(const unsigned char* b) {
    T v;
    std::memcpy(&v, b, sizeof(T));
    return double(v);
  }

  std::string_view data_;
  size_t pos_;
  bool big_endian_;
};

// The mesh-relevant reading of one element instance: scalar property values
// (by property order) and, for the first list property, its items.
struct PlyInstance {
  std::vector<double> scalars;
  std::vector<double> list;
};

bool IsFaceList(const PlyProperty& p) {
  return p.is_list && (p.name == "vertex_indices" || p.name == "vertex_index");
}

// Empty when the index is valid, else what is wrong with it.
std::string CheckIndex(double v, size_t vertex_count) {
  if (!(v >= 0) || v != std::floor(v) || v >= double(vertex_count))
    return Cat("face index ", v, " out of range (", vertex_count, " vertices)");
  return {};
}

}  // namespace

absl::StatusOr<TriangleMesh> ParsePly(std::string_view data, std::string_view name) {
  LineReader reader(data);
  std::string_view line;
  if (!reader.Next(line) || Trim(line) != "ply")
    return LineError(name, 1, "not a PLY file (missing 'ply' magic)");
  std::optional<PlyFormat> format;
  std::vector<PlyElement> elements;
  bool ended = false;
  while (reader.Next(line)) {
    const int ln = reader.line_number();
    const std::vector<std::string_view> tok = Tokens(line);
    if (tok.empty() || tok[0] == "comment" || tok[0] == "obj_info") continue;
    if (tok[0] == "end_header") {
      ended = true;
      break;
    }
    if (tok[0] == "format") {
      if (tok.size() < 2) return LineError(name, ln, "format line needs a format");
      if (tok[1] == "ascii") {
        format = PlyFormat::kAscii;
      } else if (tok[1] == "binary_little_endian") {
        format = PlyFormat::kBinaryLittle;
      } else if (tok[1] == "binary_big_endian") {
        format = PlyFormat::kBinaryBig;
      } else {
        return LineError(name, ln, Cat("unknown PLY format '", tok[1], "'"));
      }
    } else if (tok[0] == "element") {
      int64_t count;
      if (tok.size() != 3 || !ParseInt(tok[2], count) || count < 0)
        return LineError(name, ln, "element line must be 'element <name> <count>'");
      elements.push_back({std::string(tok[1]), uint64_t(count), {}});
    } else if (tok[0] == "property") {
      if (elements.empty()) return LineError(name, ln, "property before any element");
      PlyProperty p;
      if (tok.size() == 5 && tok[1] == "list") {
        p.is_list = true;
        if (!ParsePlyType(tok[2], p.count_type) || !ParsePlyType(tok[3], p.type))
          return LineError(name, ln, "unknown property type");
        p.name = std::string(tok[4]);
      } else if (tok.size() == 3) {
        if (!ParsePlyType(tok[1], p.type))
          return LineError(name, ln, Cat("unknown property type '", tok[1], "'"));
        p.name = std::string(tok[2]);
      } else {
        return LineError(name, ln, "malformed property line");
      }
      elements.back().properties.push_back(std::move(p));
    } else {
      return LineError(name, ln, Cat("unexpected header keyword '", tok[0], "'"));
    }
  }
  if (!ended) return LineError(name, reader.line_number(), "PLY header has no end_header");
  if (!format) return LineError(name, reader.line_number(), "PLY header has no format line");

  // Locate the properties the mesh needs.
  const PlyElement* vertex_el = nullptr;
  const PlyElement* face_el = nullptr;
  int px = -1, py = -1, pz = -1, pface = -1;
  for (const PlyElement& e : elements) {
    if (e.name == "vertex") {
      vertex_el = &e;
      for (size_t i = 0; i < e.properties.size(); ++i) {
        if (e.properties[i].is_list) continue;
        if (e.properties[i].name == "x") px = int(i);
        if (e.properties[i].name == "y") py = int(i);
        if (e.properties[i].name == "z") pz = int(i);
      }
    } else if (e.name == "face") {
      face_el = &e;
      for (size_t i = 0; i < e.properties.size(); ++i)
        if (IsFaceList(e.properties[i])) pface = int(i);
    }
  }
  if (!vertex_el || px < 0 || py < 0 || pz < 0)
    return absl::InvalidArgumentError(
        Cat(name, ": PLY header lacks a vertex element with x, y, z properties"));
  if (face_el && pface < 0)
    return absl::InvalidArgumentError(Cat(name, ": PLY face element lacks a vertex_indices list"));

  TriangleMesh mesh;
  mesh.vertices.reserve(size_t(std::min<uint64_t>(vertex_el->count, 1 << 24)));
  std::vector<uint32_t> poly;
  const size_t vertex_count = size_t(vertex_el->count);
  // Adds one element instance to the mesh. Returns what is wrong with it,
  // or an empty string; callers add the place (messages are built only on
  // failure, which keeps large files fast).
  auto consume = [&](const PlyElement& e, const PlyInstance& inst) -> std::string {
    if (&e == vertex_el) {
      const Vec3 p{inst.scalars[size_t(px)], inst.scalars[size_t(py)], inst.scalars[size_t(pz)]};
      if (!IsFinite(p)) return "non-finite vertex coordinate";
      mesh.vertices.push_back(p);
    } else if (&e == face_el) {
      if (inst.list.size() < 3) return "face with fewer than 3 corners";
      poly.clear();
      for (double v : inst.list) {
        // Indices refer to the header's vertex count, so faces may come first.
        if (std::string error = CheckIndex(v, vertex_count); !error.empty()) return error;
        poly.push_back(uint32_t(v));
      }
      AddPolygon(poly, mesh);
    }
    return {};
  };

  PlyInstance inst;
  if (*format == PlyFormat::kAscii) {
    for (const PlyElement& e : elements) {
      for (uint64_t i = 0; i < e.count; ++i) {
        std::vector<std::string_view> tok;
        do {
          if (!reader.Next(line)) {
            return LineError(
                name, reader.line_number() + 1,
                Cat("file ends inside element '", e.name, "' (", i, " of ", e.count, " read)"));
          }
          tok = Tokens(line);
        } while (tok.empty());
        const int ln = reader.line_number();
        inst.scalars.assign(e.properties.size(), 0);
        inst.list.clear();
        size_t t = 0;
        for (size_t pi = 0; pi < e.properties.size(); ++pi) {
          const PlyProperty& p = e.properties[pi];
          if (t >= tok.size()) return LineError(name, ln, "too few values for element");
          double v;
          if (!ParseDouble(tok[t++], v))
            return LineError(name, ln, Cat("bad number '", tok[t - 1], "'"));
          if (!p.is_list) {
            inst.scalars[pi] = v;
            continue;
          }
          if (!(v >= 0) || v != std::floor(v)) return LineError(name, ln, "bad list length");
          if (v > double(tok.size() - t))
            return LineError(name, ln, "list shorter than its length");
          const size_t n = size_t(v);
          for (size_t k = 0; k < n; ++k) {
            double item;
            if (!ParseDouble(tok[t + k], item))
              return LineError(name, ln, Cat("bad number '", tok[t + k], "'"));
            if (&e == face_el && int(pi) == pface) inst.list.push_back(item);
          }
          t += n;
        }
        if (std::string error = consume(e, inst); !error.empty()) return LineError(name, ln, error);
      }
    }
  } else {
    BinaryCursor cur(data, reader.position(), *format == PlyFormat::kBinaryBig);
    for (const PlyElement& e : elements) {
      for (uint64_t i = 0; i < e.count; ++i) {
        const size_t start = cur.position();
        auto truncated = [&]() {
          return OffsetError(name, cur.position(),
                             Cat("truncated binary PLY inside ", e.name, " ", i, " of ", e.count,
                                 " (file is ", data.size(), " bytes)"));
        };
        inst.scalars.assign(e.properties.size(), 0);
        inst.list.clear();
        for (size_t pi = 0; pi < e.properties.size(); ++pi) {
          const PlyProperty& p = e.properties[pi];
          double v;
          if (!p.is_list) {
            if (!cur.Read(p.type, v)) return truncated();
            inst.scalars[pi] = v;
            continue;
          }
          if (!cur.Read(p.count_type, v)) return truncated();
          // Longer lists than the remaining bytes are truncated files.
          if (!(v >= 0) || v != std::floor(v) || v > double(data.size()))
            return OffsetError(name, cur.position(), Cat("bad list length ", v));
          const bool keep = &e == face_el && int(pi) == pface;
          for (size_t k = 0; k < size_t(v); ++k) {
            double item;
            if (!cur.Read(p.type, item)) return truncated();
            if (keep) inst.list.push_back(item);
          }
        }
        if (std::string error = consume(e, inst); !error.empty())
          return OffsetError(name, start, Cat(e.name, " ", i, ": ", error));
      }
    }
  }
  return mesh;
}

// ---------------------------------------------------------------- STL

namespace {

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
  if (data.size() < 84) {
    return OffsetError(
        name, data.size(),
        Cat("truncated binary STL: ", data.size(), " bytes is shorter than the 84-byte header"));
  }
  uint32_t n;
  std::memcpy(&n, data.data() + 80, 4);
  const uint64_t need = 84 + uint64_t(n) * 50;
  if (data.size() < need) {
    const uint64_t whole = (data.size() - 84) / 50;
    return OffsetError(name, 84 + whole * 50,
                       Cat("truncated binary STL: header declares ", n, " triangles (", need,
                           " bytes) but the file has ", data.size(), " bytes"));
  }
  TriangleMesh mesh;
  mesh.vertices.reserve(size_t(n) * 3);
  mesh.triangles.reserve(n);
  for (uint32_t t = 0; t < n; ++t) {
    const size_t base = 84 + size_t(t) * 50;
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

}  // namespace

absl::StatusOr<TriangleMesh> ParseStl(std::string_view data, std::string_view name) {
  if (LooksLikeAsciiStl(data)) return ParseAsciiStl(data, name);
  return ParseBinaryStl(data, name);
}

// ---------------------------------------------------------------- common

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

absl::StatusOr<TriangleMesh> LoadMesh(const std::filesystem::path& path) {
  const std::string name = path.string();
  std::ifstream in(path, std::ios::binary);
  if (!in) return absl::NotFoundError(Cat(name, ": cannot open mesh file"));
  std::ostringstream buf;
  buf << in.rdbuf();
  const std::string data = std::move(buf).str();
  std::string ext = path.extension().string();
  absl::AsciiStrToLower(&ext);

  absl::StatusOr<TriangleMesh> mesh;
  if (std::string_view(data).starts_with("ply\n") ||
      std::string_view(data).starts_with("ply\r\n")) {
    mesh = ParsePly(data, name);
  } else if (ext == ".stl") {
    mesh = ParseStl(data, name);
  } else if (ext == ".obj") {
    mesh = ParseObj(data, name);
  } else if (ext == ".ply") {
    mesh = ParsePly(data, name);  // reports the missing magic
  } else {
    return absl::InvalidArgumentError(
        Cat(name, ": unknown mesh format (expected .obj, .ply or .stl)"));
  }
  if (!mesh.ok()) return mesh.status();
  if (absl::Status s = ValidateMesh(*mesh, name); !s.ok()) return s;
  return mesh;
}

namespace {

// Appends printf-formatted text (number formatting only; inputs are ours).
template <typename... Args>
void AppendF(std::string& out, const char* fmt, Args... args) {
  char buf[160];
  const int n = std::snprintf(buf, sizeof(buf), fmt, args...);
  out.append(buf, size_t(std::max(0, std::min(n, int(sizeof(buf)) - 1))));
}

void AppendRaw(std::string& out, const void* p, size_t n) {
  out.append(static_cast<const char*>(p), n);
}

Vec3 FaceNormal(const TriangleMesh& m, const std::array<uint32_t, 3>& t) {
  const Vec3 a = m.vertices[t[0]];
  const Vec3 n = Cross(m.vertices[t[1]] - a, m.vertices[t[2]] - a);
  const double len = Length(n);
  return len > 0 ? (1.0 / len) * n : Vec3{};
}

}  // namespace

std::string SerializeMesh(const TriangleMesh& mesh, MeshFormat format) {
  std::string out;
  switch (format) {
    case MeshFormat::kObj:
      for (const Vec3& v : mesh.vertices) AppendF(out, "v %.17g %.17g %.17g\n", v.x, v.y, v.z);
      for (const auto& t : mesh.triangles)
        absl::StrAppend(&out, "f ", t[0] + 1, " ", t[1] + 1, " ", t[2] + 1, "\n");
      break;
    case MeshFormat::kPlyAscii:
    case MeshFormat::kPlyBinary: {
      const bool binary = format == MeshFormat::kPlyBinary;
      absl::StrAppend(&out, "ply\nformat ", binary ? "binary_little_endian" : "ascii",
                      " 1.0\ncomment written by nimbus\nelement vertex ", mesh.vertices.size(),
                      "\nproperty double x\nproperty double y\nproperty double z\nelement face ",
                      mesh.triangles.size(),
                      "\nproperty list uchar uint vertex_indices\nend_header\n");
      for (const Vec3& v : mesh.vertices) {
        if (binary) {
          AppendRaw(out, &v.x, 8);
          AppendRaw(out, &v.y, 8);
          AppendRaw(out, &v.z, 8);
        } else {
          AppendF(out, "%.17g %.17g %.17g\n", v.x, v.y, v.z);
        }
      }
      for (const auto& t : mesh.triangles) {
        if (binary) {
          const uint8_t n = 3;
          AppendRaw(out, &n, 1);
          AppendRaw(out, t.data(), 12);
        } else {
          absl::StrAppend(&out, "3 ", t[0], " ", t[1], " ", t[2], "\n");
        }
      }
      break;
    }
    case MeshFormat::kStlAscii:
      out = "solid nimbus\n";
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
      break;
    case MeshFormat::kStlBinary: {
      out.assign(80, ' ');
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
      break;
    }
  }
  return out;
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
