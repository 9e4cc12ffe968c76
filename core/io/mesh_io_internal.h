// Text and binary helpers shared by the per-format mesh readers and writers
// (mesh_obj.cc, mesh_ply.cc, mesh_stl.cc). Not part of the public API.
#pragma once

#include <algorithm>
#include <charconv>
#include <cstdint>
#include <cstdio>
#include <sstream>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/io/mesh_io.h"

namespace nimbus::mesh_internal {

// absl::string_view is not std::string_view in this abseil build, so error
// messages are assembled with a stream.
template <typename... Args>
std::string Cat(const Args&... args) {
  std::ostringstream os;
  os.precision(17);
  (os << ... << args);
  return os.str();
}

inline bool IsSpace(char c) {
  return c == ' ' || c == '\t' || c == '\f' || c == '\v' || c == '\r' || c == '\n';
}

inline std::string_view Trim(std::string_view s) {
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

inline std::vector<std::string_view> Tokens(std::string_view line) {
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

inline bool ParseDouble(std::string_view s, double& out) {
  if (!s.empty() && s.front() == '+') s.remove_prefix(1);
  const auto [ptr, ec] = std::from_chars(s.data(), s.data() + s.size(), out);
  return ec == std::errc() && ptr == s.data() + s.size();
}

inline bool ParseInt(std::string_view s, int64_t& out) {
  if (!s.empty() && s.front() == '+') s.remove_prefix(1);
  const auto [ptr, ec] = std::from_chars(s.data(), s.data() + s.size(), out);
  return ec == std::errc() && ptr == s.data() + s.size();
}

inline absl::Status LineError(std::string_view name, int line, std::string_view what) {
  return absl::InvalidArgumentError(Cat(name, ":", line, ": ", what));
}

inline absl::Status OffsetError(std::string_view name, size_t offset, std::string_view what) {
  return absl::InvalidArgumentError(Cat(name, ": byte offset ", offset, ": ", what));
}

// The three coordinates of an OBJ "v" or ASCII STL "vertex" line, tok[1..3].
inline absl::Status ParseVertex(const std::vector<std::string_view>& tok, std::string_view name,
                                int ln, Vec3& p) {
  if (tok.size() < 4) return LineError(name, ln, "vertex needs three coordinates");
  for (int a = 0; a < 3; ++a) {
    if (!ParseDouble(tok[1 + a], p[a]))
      return LineError(name, ln, Cat("bad vertex coordinate '", tok[1 + a], "'"));
  }
  if (!IsFinite(p)) return LineError(name, ln, "non-finite vertex coordinate");
  return absl::OkStatus();
}

// Most corners a polygon of a mesh file may have. Polygons are fan-split
// into corners - 2 triangles that all share the first corner, so a huge
// one is a small file that voxelises as a huge mesh.
inline constexpr size_t kMaxPolygonCorners = 4096;

// The error for a face of `corners` > kMaxPolygonCorners corners.
inline std::string TooManyCorners(size_t corners) {
  return Cat("face has ", corners, " corners; at most ", kMaxPolygonCorners,
             " are allowed (split it into smaller faces)");
}

// Fan-splits a polygon given by vertex indices.
inline void AddPolygon(const std::vector<uint32_t>& poly, TriangleMesh& mesh) {
  for (size_t k = 1; k + 1 < poly.size(); ++k)
    mesh.triangles.push_back({poly[0], poly[k], poly[k + 1]});
}

// Appends printf-formatted text (number formatting only; inputs are ours).
template <typename... Args>
void AppendF(std::string& out, const char* fmt, Args... args) {
  char buf[160];
  const int n = std::snprintf(buf, sizeof(buf), fmt, args...);
  out.append(buf, size_t(std::max(0, std::min(n, int(sizeof(buf)) - 1))));
}

inline void AppendRaw(std::string& out, const void* p, size_t n) {
  out.append(static_cast<const char*>(p), n);
}

// Per-format writers behind SerializeMesh.
std::string SerializeObj(const TriangleMesh& mesh);
std::string SerializePly(const TriangleMesh& mesh, bool binary);
std::string SerializeStl(const TriangleMesh& mesh, bool binary);

/// True when `data` is an STL file by content alone: an ASCII "solid …
/// facet" opening, or a binary file whose size matches its triangle count.
bool LooksLikeStl(std::string_view data);

}  // namespace nimbus::mesh_internal
