#include "core/io/vdb_native.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <map>
#include <memory>
#include <set>
#include <stdexcept>
#include <utility>

#include "core/base/zero_pages.h"
#include "core/io/blosc_lz4.h"

namespace nimbus::vdb_native {

namespace {

// The archive's compression flags: COMPRESS_BLOSC | COMPRESS_ACTIVE_MASK.
constexpr uint32_t kCompression = 0x4 | 0x2;
// OpenVDB 10's file format and library version.
constexpr uint32_t kFileVersion = 224, kLibraryMajor = 10, kLibraryMinor = 0;
// StreamCompression's limits: no Blosc at or below 48 bytes, and buffers
// below 128 bytes zero-padded to 128 before compressing.
constexpr size_t kBloscMinimumBytes = 48, kBloscPadBytes = 128;

// Bytes built once and written out, which a large grid's topology is: from
// 1 MiB on in huge pages (ZeroPageAllocator), a few faults instead of one
// per 4 KiB (some 250 for a 1024^2 picture's leaf masks).
using BigBytes = std::basic_string<char, std::char_traits<char>, ZeroPageAllocator<char>>;

template <typename T, typename Out>
void Put(Out& out, const T& v) {
  out.append(reinterpret_cast<const char*>(&v), sizeof(T));
}

void PutString(std::string& out, const std::string& s) {
  Put(out, uint32_t(s.size()));
  out += s;
}

// compression::bloscCompress (StreamCompression): the compressed bytes,
// or empty when too small to try, when Blosc fails or when it saves nothing.
std::string PaddedBloscCompress(const char* data, size_t n) {
  if (n <= kBloscMinimumBytes) return {};
  size_t room = n < kBloscPadBytes ? n + kBloscPadBytes : n;
  room += kBloscOverhead;
  std::string padded;
  const char* in = data;
  size_t in_bytes = n;
  if (n < kBloscPadBytes) {
    padded.assign(kBloscPadBytes, '\0');
    std::memcpy(padded.data(), data, n);
    in = padded.data(), in_bytes = kBloscPadBytes;
  }
  std::string out(room, '\0');
  const int bytes = BloscLz4(in, in_bytes, out.data(), room);
  if (bytes <= 0 || size_t(bytes) >= n) return {};
  out.resize(size_t(bytes));
  return out;
}

// DelayedLoadMetadata::writeValue: the leaf count, then the masks and the
// sizes, each Blosc-compressed when that pays (int32 byte count first, 0
// for raw bytes).
std::string DelayedLoadValue(const std::vector<int8_t>& mask, const std::vector<int64_t>& size) {
  std::string out;
  if (mask.empty()) return out;
  Put(out, uint32_t(mask.size()));
  auto put_array = [&](const char* data, size_t n) {
    const std::string packed = PaddedBloscCompress(data, n);
    Put(out, uint32_t(packed.size()));
    if (packed.empty())
      out.append(data, n);
    else
      out += packed;
  };
  put_array(reinterpret_cast<const char*>(mask.data()), mask.size());
  put_array(reinterpret_cast<const char*>(size.data()), size.size() * sizeof(int64_t));
  return out;
}

}  // namespace

uint16_t FloatToHalf(float f) {
  uint32_t u;
  std::memcpy(&u, &f, sizeof(u));
  const uint16_t sign = uint16_t((u >> 16) & 0x8000);
  uint32_t a = u & 0x7fffffff;
  if (a >= 0x7f800000) {  // infinity, or NaN with its top mantissa bits (never 0)
    if (a == 0x7f800000) return sign | 0x7c00;
    const uint32_t m = (a & 0x7fffff) >> 13;
    return uint16_t(sign | 0x7c00 | m | (m == 0));
  }
  if (a >= 0x477ff000) return sign | 0x7c00;  // rounds past 65504
  if (a >= 0x38800000) {                      // a normal half: rebias, round the mantissa
    a -= 0x38000000;
    return uint16_t(sign | ((a + 0x0fff + ((a >> 13) & 1)) >> 13));
  }
  if (a < 0x33000001) return sign;  // at most half the smallest subnormal: zero
  // A subnormal half: the 24-bit significand shifted into units of 2^-24.
  const uint32_t shift = 126 - (a >> 23);
  const uint32_t m = (a & 0x7fffff) | 0x800000;
  uint32_t r = m >> shift;
  const uint32_t rest = m & ((1u << shift) - 1), half = 1u << (shift - 1);
  if (rest > half || (rest == half && (r & 1))) ++r;
  return uint16_t(sign | r);
}

size_t ValueBytes(ValueKind kind) {
  switch (kind) {
    case ValueKind::kFloat:
      return 4;
    case ValueKind::kVec3f:
      return 12;
    case ValueKind::kInt64:
      return 8;
  }
  return 4;
}

void BloscToStream(const char* data, size_t n, std::string& out) {
  const size_t room = n + kBloscOverhead;
  const size_t at = out.size();
  out.resize(at + sizeof(int64_t) + room);
  const int bytes = BloscLz4(data, n, out.data() + at + sizeof(int64_t), room);
  if (bytes <= 0) {
    out.resize(at);
    Put(out, -int64_t(n));
    out.append(data, n);
    return;
  }
  const int64_t size = bytes;
  std::memcpy(out.data() + at, &size, sizeof(size));
  out.resize(at + sizeof(int64_t) + size_t(bytes));
}

int64_t EncodeLeaf(ValueKind kind, bool half, const LeafMask& mask, const void* active,
                   size_t count, std::string& out) {
  out.append(reinterpret_cast<const char*>(mask.data()), sizeof(LeafMask));
  out += '\0';  // NO_MASK_OR_INACTIVE_VALS: every inactive value is the background
  const size_t start = out.size();
  if (half && kind != ValueKind::kInt64) {
    // HalfWriter writes nothing at all for no values.
    if (count == 0) return 8;  // ...but the delayed-load size counts a prefix
    const size_t n = count * (kind == ValueKind::kVec3f ? 3 : 1);
    std::vector<uint16_t> halves(n);
    const float* f = static_cast<const float*>(active);
    for (size_t i = 0; i < n; ++i) halves[i] = FloatToHalf(f[i]);
    BloscToStream(reinterpret_cast<const char*>(halves.data()), n * 2, out);
  } else {
    BloscToStream(static_cast<const char*>(active), count * ValueBytes(kind), out);
  }
  return int64_t(out.size() - start);
}

// ---- Metadata ----

void MetaMap::String(const std::string& key, const std::string& value) {
  Raw(key, "string", value);
}
void MetaMap::Int64(const std::string& key, int64_t value) {
  Raw(key, "int64", std::string(reinterpret_cast<const char*>(&value), sizeof(value)));
}
void MetaMap::Double(const std::string& key, double value) {
  Raw(key, "double", std::string(reinterpret_cast<const char*>(&value), sizeof(value)));
}
void MetaMap::Bool(const std::string& key, bool value) { Raw(key, "bool", std::string(1, value)); }
void MetaMap::Vec3i(const std::string& key, int32_t x, int32_t y, int32_t z) {
  std::string b;
  Put(b, x), Put(b, y), Put(b, z);
  Raw(key, "vec3i", std::move(b));
}
void MetaMap::Vec3d(const std::string& key, double x, double y, double z) {
  std::string b;
  Put(b, x), Put(b, y), Put(b, z);
  Raw(key, "vec3d", std::move(b));
}
void MetaMap::Raw(const std::string& key, const std::string& type, std::string bytes) {
  entries_[key] = {type, std::move(bytes)};
}
void MetaMap::Write(std::string& out) const {
  Put(out, int32_t(entries_.size()));
  for (const auto& [key, entry] : entries_) {
    PutString(out, key);
    PutString(out, entry.first);
    Put(out, int32_t(entry.second.size()));
    out += entry.second;
  }
}

// ---- Transform ----

namespace {

using Vec3d = std::array<double, 3>;

// Mat4::transform of a row vector: p * m, the terms summed as OpenVDB does.
Vec3d Apply(const double (&m)[4][4], const Vec3d& p) {
  Vec3d out;
  for (int j = 0; j < 3; ++j) out[j] = p[0] * m[0][j] + p[1] * m[1][j] + p[2] * m[2][j] + m[3][j];
  return out;
}

// math::isDiagonal of the n x n corner: the off-diagonal magnitudes sum to
// within 1e-15 of zero.
bool IsDiagonal(const double (&m)[4][4], int n) {
  double sum = 0;
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j)
      if (i != j) sum += std::abs(m[i][j]);
  return !(std::abs(sum) > 1e-15);
}

bool ApproxEqual(double a, double b) { return !(std::abs(a - b) > 1e-15); }

void PutVec(std::string& out, const Vec3d& v) { Put(out, v); }

// ScaleMap's values (scale, voxel size, inverse, inverse squared, half
// inverse), as its constructor derives them.
void PutScaleValues(std::string& out, const Vec3d& s) {
  Vec3d size, inv, inv_sqr, inv_twice;
  for (int i = 0; i < 3; ++i) {
    size[i] = std::abs(s[i]);
    inv[i] = 1.0 / s[i];
    inv_sqr[i] = inv[i] * inv[i];
    inv_twice[i] = inv[i] / 2;
  }
  PutVec(out, s), PutVec(out, size), PutVec(out, inv), PutVec(out, inv_sqr);
  PutVec(out, inv_twice);
}

enum class MapKind { kScale, kScaleTranslate, kAffine };

// simplify(AffineMap): which map the transform becomes, with its scale and
// translation where it has them.
MapKind Simplify(const double (&m)[4][4], Vec3d& scale, Vec3d& translate, bool& uniform) {
  if (IsDiagonal(m, 4)) {
    scale = Apply(m, {1, 1, 1});
    translate = {0, 0, 0};
    uniform = ApproxEqual(scale[0], scale[1]) && ApproxEqual(scale[0], scale[2]);
    return MapKind::kScale;
  }
  if (IsDiagonal(m, 3)) {
    translate = Apply(m, {0, 0, 0});
    const Vec3d one = Apply(m, {1, 1, 1});
    for (int i = 0; i < 3; ++i) scale[i] = one[i] - translate[i];
    uniform = ApproxEqual(scale[0], scale[1]) && ApproxEqual(scale[0], scale[2]);
    return MapKind::kScaleTranslate;
  }
  return MapKind::kAffine;
}

}  // namespace

std::string LinearTransform::Bytes() const {
  Vec3d scale{}, translate{};
  bool uniform = false;
  std::string out;
  switch (Simplify(m, scale, translate, uniform)) {
    case MapKind::kScale:
      PutString(out, uniform ? "UniformScaleMap" : "ScaleMap");
      if (uniform) scale = {scale[0], scale[0], scale[0]};
      PutScaleValues(out, scale);
      break;
    case MapKind::kScaleTranslate:
      PutString(out, uniform ? "UniformScaleTranslateMap" : "ScaleTranslateMap");
      if (uniform) scale = {scale[0], scale[0], scale[0]};
      PutVec(out, translate);
      PutScaleValues(out, scale);
      break;
    case MapKind::kAffine:
      PutString(out, "AffineMap");
      out.append(reinterpret_cast<const char*>(m), sizeof(m));
      break;
  }
  return out;
}

std::array<double, 3> LinearTransform::VoxelSize() const {
  Vec3d scale{}, translate{};
  bool uniform = false;
  if (Simplify(m, scale, translate, uniform) != MapKind::kAffine) {
    if (uniform) scale = {scale[0], scale[0], scale[0]};
    return {std::abs(scale[0]), std::abs(scale[1]), std::abs(scale[2])};
  }
  // AffineMap: the lengths of the images of the index axes.
  const Vec3d o = Apply(m, {0, 0, 0});
  Vec3d out;
  for (int i = 0; i < 3; ++i) {
    Vec3d e{0, 0, 0};
    e[i] = 1;
    const Vec3d p = Apply(m, e);
    const Vec3d d{p[0] - o[0], p[1] - o[1], p[2] - o[2]};
    out[i] = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
  }
  return out;
}

// ---- Topology ----

namespace {

// Child indices of a voxel coordinate in the two internal levels (32^3
// children of 128^3 voxels, 16^3 children of 8^3 voxels).
uint32_t Index5(const std::array<int32_t, 3>& o) {
  return (uint32_t((o[0] & 4095) >> 7) << 10) | (uint32_t((o[1] & 4095) >> 7) << 5) |
         uint32_t((o[2] & 4095) >> 7);
}
uint32_t Index4(const std::array<int32_t, 3>& o) {
  return (uint32_t((o[0] & 127) >> 3) << 8) | (uint32_t((o[1] & 127) >> 3) << 4) |
         uint32_t((o[2] & 127) >> 3);
}
std::array<int32_t, 3> RootKey(const std::array<int32_t, 3>& o) {
  return {o[0] & ~4095, o[1] & ~4095, o[2] & ~4095};
}
uint32_t Key4(const std::array<int32_t, 3>& o) { return (Index5(o) << 12) | Index4(o); }

// Memory per node as tools::memUsageIfLoaded counts it, per value type
// (tree and root, 32^3 node, 16^3 node, leaf); pinned by a test.
struct NodeBytes {
  uint64_t tree, n5, n4, leaf;
};
NodeBytes MemUsage(ValueKind kind) {
  switch (kind) {
    case ValueKind::kFloat:
      return {1304, 270348, 33804, 2144};
    case ValueKind::kVec3f:
      return {1320, 532492, 66572, 6240};
    case ValueKind::kInt64:
      return {1304, 270348, 33804, 4192};
  }
  return {};
}

// An internal node's tile values: none active, so the mask-compression
// byte and an empty value block (nothing at all for half floats).
void PutEmptyTiles(BigBytes& out, ValueKind kind, bool half) {
  std::string tiles(1, '\0');
  const char none = 0;
  if (!(half && kind != ValueKind::kInt64)) BloscToStream(&none, 0, tiles);
  out.append(tiles.data(), tiles.size());
}

template <size_t kWords>
void PutMask(BigBytes& out, const std::array<uint64_t, kWords>& mask) {
  out.append(reinterpret_cast<const char*>(mask.data()), kWords * sizeof(uint64_t));
}

// Tree::writeTopology for tree-ordered leaves: the buffer count, the
// root's background and child count, then each internal node's child and
// value masks and tiles followed by its children, leaves as value masks.
void PutTopology(BigBytes& out, const Grid& g, uint64_t& nodes5, uint64_t& nodes4) {
  Put(out, int32_t(1));
  out.append(ValueBytes(g.kind), '\0');  // the zero background (as a half too)
  std::vector<size_t> roots;  // first leaf of each root child
  size_t internal4 = 0;
  for (size_t i = 0; i < (*g.leaves).size(); ++i) {
    const auto& o = (*g.leaves)[i].origin;
    const auto& before = (*g.leaves)[i == 0 ? 0 : i - 1].origin;
    if (i == 0 || RootKey(o) != RootKey(before)) roots.push_back(i);
    if (i == 0 || RootKey(o) != RootKey(before) || Index5(o) != Index5(before)) ++internal4;
  }
  // Sized once (masks plus a generous allowance for keys and empty tiles):
  // doubling would fault in twice the pages.
  out.reserve(out.size() + roots.size() * (2 * 4096 + 128) + internal4 * (2 * 512 + 128) +
              (*g.leaves).size() * 64);
  Put(out, uint32_t(0));
  Put(out, uint32_t(roots.size()));
  nodes5 = roots.size(), nodes4 = 0;
  const std::array<uint64_t, 512> zero5{};
  const std::array<uint64_t, 64> zero4{};
  for (size_t r = 0; r < roots.size(); ++r) {
    const size_t end = r + 1 < roots.size() ? roots[r + 1] : (*g.leaves).size();
    Put(out, RootKey((*g.leaves)[roots[r]].origin));
    std::array<uint64_t, 512> children5{};
    for (size_t i = roots[r]; i < end; ++i) {
      const uint32_t n = Index5((*g.leaves)[i].origin);
      children5[n >> 6] |= uint64_t{1} << (n & 63);
    }
    PutMask(out, children5), PutMask(out, zero5);
    PutEmptyTiles(out, g.kind, g.half);
    for (size_t i = roots[r]; i < end;) {
      size_t j = i;
      std::array<uint64_t, 64> children4{};
      for (; j < end && Index5((*g.leaves)[j].origin) == Index5((*g.leaves)[i].origin); ++j) {
        const uint32_t n = Index4((*g.leaves)[j].origin);
        children4[n >> 6] |= uint64_t{1} << (n & 63);
      }
      ++nodes4;
      PutMask(out, children4), PutMask(out, zero4);
      PutEmptyTiles(out, g.kind, g.half);
      for (; i < j; ++i) PutMask(out, (*g.leaves)[i].mask);
    }
  }
}

// Active-voxel bounds of one leaf, widened into [lo, hi].
void WidenBounds(const Leaf& leaf, std::array<int32_t, 3>& lo, std::array<int32_t, 3>& hi) {
  uint64_t any = 0;
  int first_x = -1, last_x = -1;
  for (int x = 0; x < 8; ++x)
    if (leaf.mask[size_t(x)]) {
      any |= leaf.mask[size_t(x)];
      if (first_x < 0) first_x = x;
      last_x = x;
    }
  if (first_x < 0) return;
  uint32_t rows = 0, zs = 0;  // which y rows, which z bits
  for (int y = 0; y < 8; ++y) {
    const uint32_t row = uint32_t(any >> (8 * y)) & 0xff;
    if (row) rows |= 1u << y, zs |= row;
  }
  const std::array<int32_t, 3> a{first_x, std::countr_zero(rows), std::countr_zero(zs)};
  const std::array<int32_t, 3> b{last_x, 31 - std::countl_zero(rows), 31 - std::countl_zero(zs)};
  for (int k = 0; k < 3; ++k) {
    lo[size_t(k)] = std::min(lo[size_t(k)], leaf.origin[size_t(k)] + a[size_t(k)]);
    hi[size_t(k)] = std::max(hi[size_t(k)], leaf.origin[size_t(k)] + b[size_t(k)]);
  }
}

// The entries Archive::writeGrid adds: delayed-load sizes, statistics
// (bounds, memory if loaded, voxel count) and the compression.
void AddFileMetadata(const Grid& g, uint64_t nodes5, uint64_t nodes4, MetaMap& meta) {
  std::array<int32_t, 3> lo{INT32_MAX, INT32_MAX, INT32_MAX}, hi{INT32_MIN, INT32_MIN, INT32_MIN};
  for (const Leaf& leaf : (*g.leaves)) WidenBounds(leaf, lo, hi);
  meta.Vec3i("file_bbox_min", lo[0], lo[1], lo[2]);
  meta.Vec3i("file_bbox_max", hi[0], hi[1], hi[2]);
  meta.String("file_compression", "blosc + active values");
  meta.Raw("file_delayed_load", "__delayedload", DelayedLoadValue(g.delayed_mask, g.delayed_size));
  const NodeBytes b = MemUsage(g.kind);
  meta.Int64("file_mem_bytes",
             int64_t(b.tree + nodes5 * b.n5 + nodes4 * b.n4 + (*g.leaves).size() * b.leaf));
  meta.Int64("file_voxel_count", int64_t(g.active_voxels));
}

std::string TypeName(const Grid& g) {
  const char* base = g.kind == ValueKind::kFloat   ? "Tree_float_5_4_3"
                     : g.kind == ValueKind::kVec3f ? "Tree_vec3s_5_4_3"
                                                   : "Tree_int64_5_4_3";
  return std::string(base) + (g.half ? "_HalfFloat" : "");
}

// Archive::write's numbering of repeated or empty names (GridDescriptor::
// addSuffix: the name, ASCII record separator, the number).
std::string UniqueName(const std::string& name, std::map<std::string, int>& repeats,
                       std::set<std::string>& used) {
  auto suffixed = [&](int n) { return name + "\x1e" + std::to_string(n); };
  std::string unique = name;
  if (name.empty() || repeats[name] > 1) unique = suffixed(0);
  for (int n = 1; used.count(unique) > 0; ++n) unique = suffixed(n);
  used.insert(unique);
  return unique;
}

// Archive::writeGrid: descriptor, the three stream positions, then the
// grid's compression, metadata, transform, topology and leaf buffers. The
// positions are known before the bytes they point at, so the file is
// written front to back (which lets the writer hash it on the way).
void WriteGrid(std::ostream& os, const std::string& unique, const Grid& g) {
  std::string head;
  PutString(head, unique);
  PutString(head, TypeName(g));
  PutString(head, "");  // no instance parent
  std::string body;
  BigBytes topology;
  uint64_t nodes5 = 0, nodes4 = 0;
  PutTopology(topology, g, nodes5, nodes4);
  MetaMap meta = g.meta;
  AddFileMetadata(g, nodes5, nodes4, meta);
  Put(body, kCompression);
  meta.Write(body);
  body += g.transform.Bytes();
  int64_t pos[3];
  pos[0] = int64_t(os.tellp()) + int64_t(head.size() + sizeof(pos));
  pos[1] = pos[0] + int64_t(body.size() + topology.size());
  pos[2] = pos[1] + int64_t(g.buffers.bytes());
  os.write(head.data(), std::streamsize(head.size()));
  os.write(reinterpret_cast<const char*>(pos), sizeof(pos));
  os.write(body.data(), std::streamsize(body.size()));
  os.write(topology.data(), std::streamsize(topology.size()));
  g.buffers.WriteTo(os);
  if (!os) throw std::runtime_error("stream failure writing grid " + g.name);
  if (int64_t(os.tellp()) != pos[2])
    throw std::logic_error("grid " + g.name + " ends elsewhere than its header says");
}

}  // namespace

void SortTreeOrder(LeafList& leaves) {
  std::sort(leaves.begin(), leaves.end(), [](const Leaf& a, const Leaf& b) {
    const auto ra = RootKey(a.origin), rb = RootKey(b.origin);
    if (ra != rb) return ra < rb;
    return Key4(a.origin) < Key4(b.origin);
  });
}

void EncodeLeaves(Grid& g, const std::function<void(const Leaf&, void*)>& fill,
                  const std::function<void(const Leaf&, const void*, size_t)>& visit) {
  const size_t n = (*g.leaves).size(), vb = ValueBytes(g.kind);
  g.delayed_mask.assign(n, 0);
  g.delayed_size.assign(n, 0);
  // Runs of leaves bound the scratch; enough leaves per task to amortise it.
  constexpr size_t kChunk = 256;
  std::vector<std::string> bytes(std::min(n, kChunk));
  // Written before read; from the kernel in huge pages (see ZeroPageAllocator).
  std::vector<char, ZeroPageAllocator<char>> packed(std::min(n, kChunk) * 512 * vb);
  std::vector<size_t> counts(bytes.size());
  BigBytes run;  // one chunk's encodings; its capacity is kept for the next
  for (size_t first = 0; first < n; first += kChunk) {
    const size_t count = std::min(kChunk, n - first);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, count, 32), [&](const auto& r) {
      for (size_t j = r.begin(); j < r.end(); ++j) {
        const Leaf& leaf = (*g.leaves)[first + j];
        char* out = packed.data() + j * 512 * vb;
        fill(leaf, out);
        size_t k = 0;
        for (uint64_t w : leaf.mask) k += size_t(std::popcount(w));
        counts[j] = k;
        bytes[j].clear();
        g.delayed_size[first + j] = EncodeLeaf(g.kind, g.half, leaf.mask, out, k, bytes[j]);
      }
    });
    run.clear();
    for (size_t j = 0; j < count; ++j) {
      run += bytes[j];
      g.active_voxels += counts[j];
      visit((*g.leaves)[first + j], packed.data() + j * 512 * vb, counts[j]);
    }
    g.buffers.Append({run.data(), run.size()});
  }
}

void WriteArchive(std::ostream& os, const std::vector<GridSource>& grids) {
  std::string head;
  Put(head, int64_t(0x56444220));
  Put(head, kFileVersion), Put(head, kLibraryMajor), Put(head, kLibraryMinor);
  head += '\1';  // grid offsets follow each descriptor
  head += "00000000-0000-0000-0000-000000000000";  // stamped from the content later
  Put(head, int32_t(0));                           // no file metadata
  Put(head, int32_t(grids.size()));
  os.write(head.data(), std::streamsize(head.size()));
  std::map<std::string, int> repeats;
  for (const GridSource& s : grids) ++repeats[s.name];
  std::set<std::string> used;
  for (const GridSource& s : grids) {
    const Grid g = s.make();
    WriteGrid(os, UniqueName(s.name, repeats, used), g);
  }
}

}  // namespace nimbus::vdb_native
