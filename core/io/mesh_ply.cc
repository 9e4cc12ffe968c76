// PLY (ASCII, binary little- and big-endian): the header is parsed in full,
// then only the vertex positions and the face index lists are kept.
#include <bit>
#include <cmath>
#include <cstring>
#include <optional>

#include "absl/strings/str_cat.h"
#include "core/io/mesh_io.h"
#include "core/io/mesh_io_internal.h"

namespace nimbus {

using namespace mesh_internal;  // NOLINT: this file's own helpers

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

struct PlyHeader {
  PlyFormat format = PlyFormat::kAscii;
  std::vector<PlyElement> elements;
};

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
// (by property order) and, for the face list property, its items.
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

// One "format", "element" or "property" header line into `header`.
absl::Status ParseHeaderLine(const std::vector<std::string_view>& tok, std::string_view name,
                             int ln, std::optional<PlyFormat>& format, PlyHeader& header) {
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
    header.elements.push_back({std::string(tok[1]), uint64_t(count), {}});
  } else if (tok[0] == "property") {
    if (header.elements.empty()) return LineError(name, ln, "property before any element");
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
    header.elements.back().properties.push_back(std::move(p));
  } else {
    return LineError(name, ln, Cat("unexpected header keyword '", tok[0], "'"));
  }
  return absl::OkStatus();
}

// Reads the header up to end_header; `reader` is then at the body.
absl::StatusOr<PlyHeader> ParseHeader(LineReader& reader, std::string_view name) {
  std::string_view line;
  if (!reader.Next(line) || Trim(line) != "ply")
    return LineError(name, 1, "not a PLY file (missing 'ply' magic)");
  std::optional<PlyFormat> format;
  PlyHeader header;
  bool ended = false;
  while (reader.Next(line)) {
    const std::vector<std::string_view> tok = Tokens(line);
    if (tok.empty() || tok[0] == "comment" || tok[0] == "obj_info") continue;
    if (tok[0] == "end_header") {
      ended = true;
      break;
    }
    if (absl::Status st = ParseHeaderLine(tok, name, reader.line_number(), format, header);
        !st.ok())
      return st;
  }
  if (!ended) return LineError(name, reader.line_number(), "PLY header has no end_header");
  if (!format) return LineError(name, reader.line_number(), "PLY header has no format line");
  // An element with instances but no properties reads no bytes per
  // instance: a huge count would loop without ever reaching the file's end.
  for (const PlyElement& e : header.elements)
    if (e.count > 0 && e.properties.empty())
      return LineError(name, reader.line_number(),
                       Cat("element '", e.name, "' has ", e.count, " instances but no properties"));
  header.format = *format;
  return header;
}

// Collects the mesh from element instances, knowing which element and
// properties carry positions and faces.
class MeshBuilder {
 public:
  // Finds the vertex x/y/z and the face index list, or says what is missing.
  absl::Status Locate(const PlyHeader& header, std::string_view name) {
    for (const PlyElement& e : header.elements) {
      // A second vertex or face element would pair one element's property
      // indices with the other's instances (a fuzzer-found overflow).
      if ((e.name == "vertex" && vertex_el_) || (e.name == "face" && face_el_))
        return absl::InvalidArgumentError(
            Cat(name, ": PLY header has more than one '", e.name, "' element"));
      if (e.name == "vertex") {
        vertex_el_ = &e;
        for (size_t i = 0; i < e.properties.size(); ++i) {
          if (e.properties[i].is_list) continue;
          if (e.properties[i].name == "x") px_ = int(i);
          if (e.properties[i].name == "y") py_ = int(i);
          if (e.properties[i].name == "z") pz_ = int(i);
        }
      } else if (e.name == "face") {
        face_el_ = &e;
        for (size_t i = 0; i < e.properties.size(); ++i)
          if (IsFaceList(e.properties[i])) pface_ = int(i);
      }
    }
    if (!vertex_el_ || px_ < 0 || py_ < 0 || pz_ < 0)
      return absl::InvalidArgumentError(
          Cat(name, ": PLY header lacks a vertex element with x, y, z properties"));
    if (face_el_ && pface_ < 0)
      return absl::InvalidArgumentError(
          Cat(name, ": PLY face element lacks a vertex_indices list"));
    vertex_count_ = size_t(vertex_el_->count);
    mesh_.vertices.reserve(size_t(std::min<uint64_t>(vertex_el_->count, 1 << 24)));
    return absl::OkStatus();
  }

  // Whether list property `pi` of `e` holds the face corners.
  bool KeepsList(const PlyElement& e, size_t pi) const {
    return &e == face_el_ && int(pi) == pface_;
  }

  // Adds one element instance. Returns what is wrong with it, or an empty
  // string; callers add the place (messages are built only on failure,
  // which keeps large files fast).
  std::string Consume(const PlyElement& e, const PlyInstance& inst) {
    if (&e == vertex_el_) {
      const Vec3 p{inst.scalars[size_t(px_)], inst.scalars[size_t(py_)],
                   inst.scalars[size_t(pz_)]};
      if (!IsFinite(p)) return "non-finite vertex coordinate";
      mesh_.vertices.push_back(p);
    } else if (&e == face_el_) {
      if (inst.list.size() < 3) return "face with fewer than 3 corners";
      if (inst.list.size() > kMaxPolygonCorners) return TooManyCorners(inst.list.size());
      poly_.clear();
      for (double v : inst.list) {
        // Indices refer to the header's vertex count, so faces may come first.
        if (std::string error = CheckIndex(v, vertex_count_); !error.empty()) return error;
        poly_.push_back(uint32_t(v));
      }
      AddPolygon(poly_, mesh_);
    }
    return {};
  }

  TriangleMesh Take() { return std::move(mesh_); }

 private:
  const PlyElement* vertex_el_ = nullptr;
  const PlyElement* face_el_ = nullptr;
  int px_ = -1, py_ = -1, pz_ = -1, pface_ = -1;
  size_t vertex_count_ = 0;
  TriangleMesh mesh_;
  std::vector<uint32_t> poly_;
};

// One ASCII element instance from its tokens into `inst`.
absl::Status ReadAsciiInstance(const std::vector<std::string_view>& tok, const PlyElement& e,
                               const MeshBuilder& builder, std::string_view name, int ln,
                               PlyInstance& inst) {
  inst.scalars.assign(e.properties.size(), 0);
  inst.list.clear();
  size_t t = 0;
  for (size_t pi = 0; pi < e.properties.size(); ++pi) {
    const PlyProperty& p = e.properties[pi];
    if (t >= tok.size()) return LineError(name, ln, "too few values for element");
    double v;
    if (!ParseDouble(tok[t++], v)) return LineError(name, ln, Cat("bad number '", tok[t - 1], "'"));
    if (!p.is_list) {
      inst.scalars[pi] = v;
      continue;
    }
    if (!(v >= 0) || v != std::floor(v)) return LineError(name, ln, "bad list length");
    if (v > double(tok.size() - t)) return LineError(name, ln, "list shorter than its length");
    const size_t n = size_t(v);
    const bool keep = builder.KeepsList(e, pi);
    for (size_t k = 0; k < n; ++k) {
      double item;
      if (!ParseDouble(tok[t + k], item))
        return LineError(name, ln, Cat("bad number '", tok[t + k], "'"));
      if (keep) inst.list.push_back(item);
    }
    t += n;
  }
  return absl::OkStatus();
}

absl::Status ReadAsciiBody(LineReader& reader, const PlyHeader& header, std::string_view name,
                           MeshBuilder& builder) {
  PlyInstance inst;
  std::string_view line;
  for (const PlyElement& e : header.elements) {
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
      if (auto st = ReadAsciiInstance(tok, e, builder, name, ln, inst); !st.ok()) return st;
      if (std::string error = builder.Consume(e, inst); !error.empty())
        return LineError(name, ln, error);
    }
  }
  return absl::OkStatus();
}

absl::Status ReadBinaryBody(std::string_view data, size_t start, const PlyHeader& header,
                            std::string_view name, MeshBuilder& builder) {
  BinaryCursor cur(data, start, header.format == PlyFormat::kBinaryBig);
  PlyInstance inst;
  for (const PlyElement& e : header.elements) {
    // Every instance takes at least one byte: more instances than bytes
    // left is a truncated (or hostile) file, refused before reading.
    if (e.count > data.size() - std::min(data.size(), cur.position()))
      return OffsetError(name, cur.position(),
                         Cat("truncated binary PLY: element ", e.name, " claims ", e.count,
                             " instances but ", data.size() - cur.position(), " bytes are left"));
    for (uint64_t i = 0; i < e.count; ++i) {
      const size_t at = cur.position();
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
        const bool keep = builder.KeepsList(e, pi);
        for (size_t k = 0; k < size_t(v); ++k) {
          double item;
          if (!cur.Read(p.type, item)) return truncated();
          if (keep) inst.list.push_back(item);
        }
      }
      if (std::string error = builder.Consume(e, inst); !error.empty())
        return OffsetError(name, at, Cat(e.name, " ", i, ": ", error));
    }
  }
  return absl::OkStatus();
}

}  // namespace

absl::StatusOr<TriangleMesh> ParsePly(std::string_view data, std::string_view name) {
  LineReader reader(data);
  absl::StatusOr<PlyHeader> header = ParseHeader(reader, name);
  if (!header.ok()) return header.status();
  MeshBuilder builder;
  if (absl::Status st = builder.Locate(*header, name); !st.ok()) return st;
  const absl::Status body = header->format == PlyFormat::kAscii
                                ? ReadAsciiBody(reader, *header, name, builder)
                                : ReadBinaryBody(data, reader.position(), *header, name, builder);
  if (!body.ok()) return body;
  return builder.Take();
}

namespace mesh_internal {

std::string SerializePly(const TriangleMesh& mesh, bool binary) {
  std::string out;
  absl::StrAppend(&out, "ply\nformat ", binary ? "binary_little_endian" : "ascii",
                  " 1.0\ncomment written by nimbus\nelement vertex ", mesh.vertices.size(),
                  "\nproperty double x\nproperty double y\nproperty double z\nelement face ",
                  mesh.triangles.size(), "\nproperty list uchar uint vertex_indices\nend_header\n");
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
  return out;
}

}  // namespace mesh_internal
}  // namespace nimbus
