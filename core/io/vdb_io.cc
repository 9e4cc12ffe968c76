#include "core/io/vdb_io.h"

#include <openvdb/io/Stream.h>
#include <openvdb/openvdb.h>

#include <cmath>
#include <cstring>
#include <fstream>
#include <mutex>
#include <sstream>

#include "absl/strings/str_cat.h"
#include "core/base/sha256.h"
#include "core/io/vdb_internal.h"

namespace nimbus {

namespace vdb_internal {

void InitOpenVdb() {
  static std::once_flag once;
  std::call_once(once, [] { openvdb::initialize(); });
}

openvdb::math::Transform::Ptr FrameTransform(const GridFrame& frame) {
  const Vec3 h = frame.VoxelSize();
  openvdb::math::Mat4d m = openvdb::math::Mat4d::identity();
  m.setToScale(openvdb::Vec3d(h.x, h.y, h.z));
  // Index-space voxel centres sit at integer coordinates in OpenVDB.
  m.setTranslation(openvdb::Vec3d(frame.bounds.min.x + 0.5 * h.x, frame.bounds.min.y + 0.5 * h.y,
                                  frame.bounds.min.z + 0.5 * h.z));
  return openvdb::math::Transform::createLinearTransform(m);
}

void SetFrameMetadata(openvdb::GridBase& grid, const GridFrame& frame) {
  const Int3 r = frame.resolution;
  grid.insertMeta("nimbus_resolution", openvdb::Vec3IMetadata(openvdb::Vec3i(r.x, r.y, r.z)));
  const Bounds& b = frame.bounds;
  grid.insertMeta("nimbus_bounds_min",
                  openvdb::Vec3DMetadata(openvdb::Vec3d(b.min.x, b.min.y, b.min.z)));
  grid.insertMeta("nimbus_bounds_max",
                  openvdb::Vec3DMetadata(openvdb::Vec3d(b.max.x, b.max.y, b.max.z)));
}

openvdb::GridPtrVecPtr ReadAllGrids(const std::filesystem::path& path) {
  openvdb::io::File file(path.string());
  file.open();
  auto grids = file.getGrids();
  file.close();
  return grids;
}

namespace {
// OpenVDB's header: magic (8 bytes), file version, library major and minor
// (4 each), the grid-offsets flag (1), then the UUID as 36 characters.
constexpr size_t kUuidOffset = 21;
constexpr size_t kUuidSize = 36;

bool LooksLikeHeader(std::string_view head) {
  if (head.size() < kUuidOffset + kUuidSize) return false;
  int64_t magic = 0;
  std::memcpy(&magic, head.data(), sizeof(magic));
  return magic == int64_t(openvdb::OPENVDB_MAGIC) && head[kUuidOffset + 8] == '-' &&
         head[kUuidOffset + 13] == '-';
}

// A version-8 (custom) UUID from a digest's first 32 hex digits.
std::string UuidFromDigest(const std::string& hex) {
  std::string u = hex.substr(0, 32);
  u[12] = '8';
  u[16] = "89ab"[std::stoi(u.substr(16, 1), nullptr, 16) & 3];
  return u.substr(0, 8) + "-" + u.substr(8, 4) + "-" + u.substr(12, 4) + "-" + u.substr(16, 4) +
         "-" + u.substr(20, 12);
}
}  // namespace

void StampContentUuid(std::string& bytes) {
  if (!LooksLikeHeader(bytes)) return;
  Sha256 h;
  h.Update(std::string_view(bytes).substr(0, kUuidOffset));
  h.Update(std::string_view(bytes).substr(kUuidOffset + kUuidSize));
  const std::string uuid = UuidFromDigest(h.HexDigest());
  bytes.replace(kUuidOffset, kUuidSize, uuid);
}

absl::Status WriteGridsAtomically(const std::filesystem::path& path,
                                  const openvdb::GridPtrVec& grids) {
  const std::filesystem::path tmp = path.string() + ".partial";
  std::error_code ec;
  try {
    openvdb::io::File file(tmp.string());
    file.setCompression(openvdb::io::COMPRESS_BLOSC | openvdb::io::COMPRESS_ACTIVE_MASK);
    file.write(grids);
    file.close();
  } catch (const std::exception& e) {
    std::filesystem::remove(tmp, ec);
    return absl::InternalError(absl::StrCat("writing ", path.string(), ": ", e.what()));
  }
  if (auto st = StampContentUuid(tmp); !st.ok()) {
    std::filesystem::remove(tmp, ec);
    return st;
  }
  std::filesystem::rename(tmp, path, ec);
  if (ec)
    return absl::InternalError(absl::StrCat("renaming into ", path.string(), ": ", ec.message()));
  return absl::OkStatus();
}

absl::Status StampContentUuid(const std::filesystem::path& path) {
  std::fstream f(path, std::ios::in | std::ios::out | std::ios::binary);
  std::string head(kUuidOffset + kUuidSize, '\0');
  if (!f || !f.read(head.data(), std::streamsize(head.size())) || !LooksLikeHeader(head))
    return absl::InternalError(absl::StrCat(path.string(), ": not a VDB file header"));
  Sha256 h;
  h.Update(std::string_view(head).substr(0, kUuidOffset));
  std::string buf(size_t{1} << 20, '\0');
  while (f.read(buf.data(), std::streamsize(buf.size())) || f.gcount() > 0)
    h.Update(std::string_view(buf.data(), size_t(f.gcount())));
  f.clear();
  const std::string uuid = UuidFromDigest(h.HexDigest());
  f.seekp(std::streamoff(kUuidOffset));
  f.write(uuid.data(), std::streamsize(uuid.size()));
  f.close();
  if (!f) return absl::InternalError(absl::StrCat(path.string(), ": cannot stamp the UUID"));
  return absl::OkStatus();
}

}  // namespace vdb_internal

using vdb_internal::FrameTransform;
using vdb_internal::InitOpenVdb;

namespace {

const char* MappingName(DensityMapping m) {
  switch (m) {
    case DensityMapping::kLinear:
      return "linear";
    case DensityMapping::kSqrt:
      return "sqrt";
    case DensityMapping::kLog:
      return "log";
    case DensityMapping::kGamma:
      return "gamma";
  }
  return "linear";
}

// Maps a count to [0, 1] given the largest count.
struct Normaliser {
  DensityMapping mapping;
  double max, inv_max, inv_log_max, inv_gamma;
  Normaliser(const DensityOptions& o, uint32_t max_count)
      : mapping(o.mapping),
        max(std::max<double>(1, max_count)),
        inv_max(1.0 / max),
        inv_log_max(1.0 / std::log1p(max)),
        inv_gamma(1.0 / (o.gamma > 0 ? o.gamma : 1.0)) {}
  float operator()(uint32_t c) const {
    switch (mapping) {
      case DensityMapping::kLinear:
        return float(c * inv_max);
      case DensityMapping::kSqrt:
        return float(std::sqrt(c * inv_max));
      case DensityMapping::kLog:
        return float(std::log1p(double(c)) * inv_log_max);
      case DensityMapping::kGamma:
        return float(std::pow(c * inv_max, inv_gamma));
    }
    return 0.f;
  }
};

void AddMeta(openvdb::MetaMap& meta, const std::string& key, const MetaValue& v) {
  if (auto* s = std::get_if<std::string>(&v)) meta.insertMeta(key, openvdb::StringMetadata(*s));
  if (auto* i = std::get_if<int64_t>(&v)) meta.insertMeta(key, openvdb::Int64Metadata(*i));
  if (auto* d = std::get_if<double>(&v)) meta.insertMeta(key, openvdb::DoubleMetadata(*d));
}

template <typename GridT>
typename GridT::Ptr NewGrid(const std::string& name, const GridFrame& frame,
                            openvdb::GridClass cls) {
  auto grid = GridT::create();
  grid->setName(name);
  grid->setGridClass(cls);
  grid->setTransform(FrameTransform(frame));
  return grid;
}

// The density grid plus the optional Cd / address / counts grids, all with
// the same active voxels. Built leaf by leaf straight from the count tiles.
openvdb::GridPtrVec BuildGrids(const CountGrid& counts, const GridFrame& frame,
                               const DensityOptions& options, const Metadata& metadata) {
  auto grid = NewGrid<openvdb::FloatGrid>(options.grid_name, frame, openvdb::GRID_FOG_VOLUME);
  const bool color = options.color && counts.has_color();
  const bool address = options.address_grid && counts.has_color();
  openvdb::Vec3SGrid::Ptr cd;
  openvdb::FloatGrid::Ptr addr, raw_f;
  openvdb::Int64Grid::Ptr raw_i;
  if (color) cd = NewGrid<openvdb::Vec3SGrid>("Cd", frame, openvdb::GRID_UNKNOWN);
  if (address) addr = NewGrid<openvdb::FloatGrid>("address", frame, openvdb::GRID_UNKNOWN);
  if (options.raw_counts == RawCounts::kFloat)
    raw_f = NewGrid<openvdb::FloatGrid>("counts", frame, openvdb::GRID_UNKNOWN);
  if (options.raw_counts == RawCounts::kInteger)
    raw_i = NewGrid<openvdb::Int64Grid>("counts", frame, openvdb::GRID_UNKNOWN);
  const uint32_t max_count = counts.Max();
  const Normaliser norm(options, max_count);
  auto& tree = grid->tree();
  const double inv_scale = 1.0 / CountGrid::kColorScale;
  counts.ForEachTileWithColor([&](Int3 origin, const uint32_t* tile, const uint64_t* csum) {
    for (int leaf = 0; leaf < 64; ++leaf) {
      const uint32_t* v = tile + leaf * 512;
      bool any = false;
      for (int i = 0; i < 512 && !any; ++i) any = v[i] != 0;
      if (!any) continue;
      const openvdb::Coord c(origin.x + ((leaf >> 4) & 3) * 8, origin.y + ((leaf >> 2) & 3) * 8,
                             origin.z + (leaf & 3) * 8);
      auto* node = tree.touchLeaf(c);
      for (int i = 0; i < 512; ++i)
        if (v[i]) node->setValueOn(i, norm(v[i]));
      if (color || address) {
        const uint64_t* cs = csum + leaf * 512;
        auto* cd_node = color ? cd->tree().touchLeaf(c) : nullptr;
        auto* a_node = address ? addr->tree().touchLeaf(c) : nullptr;
        for (int i = 0; i < 512; ++i) {
          if (!v[i]) continue;
          const double t = double(cs[i]) * inv_scale / double(v[i]);
          if (cd_node) {
            const Vec3 rgb = options.palette.Eval(t);
            cd_node->setValueOn(i, openvdb::Vec3s(float(rgb.x), float(rgb.y), float(rgb.z)));
          }
          if (a_node) a_node->setValueOn(i, float(t));
        }
      }
      if (raw_f) {
        auto* n = raw_f->tree().touchLeaf(c);
        for (int i = 0; i < 512; ++i)
          if (v[i]) n->setValueOn(i, float(v[i]));
      }
      if (raw_i) {
        auto* n = raw_i->tree().touchLeaf(c);
        for (int i = 0; i < 512; ++i)
          if (v[i]) n->setValueOn(i, int64_t(v[i]));
      }
    }
  });
  vdb_internal::SetFrameMetadata(*grid, frame);
  grid->insertMeta("nimbus_max_count", openvdb::Int64Metadata(int64_t(max_count)));
  grid->insertMeta("nimbus_total_count", openvdb::Int64Metadata(int64_t(counts.Total())));
  grid->insertMeta("nimbus_density_mapping", openvdb::StringMetadata(MappingName(options.mapping)));
  if (options.mapping == DensityMapping::kGamma)
    grid->insertMeta("nimbus_density_gamma", openvdb::DoubleMetadata(options.gamma));
  if (color)
    grid->insertMeta("nimbus_palette",
                     openvdb::StringMetadata(options.palette.is_sine() ? "sine" : "stops"));
  for (const auto& [k, v] : metadata) AddMeta(*grid, k, v);
  openvdb::GridPtrVec out{grid};
  if (cd) out.push_back(cd);
  if (addr) out.push_back(addr);
  if (raw_f) out.push_back(raw_f);
  if (raw_i) out.push_back(raw_i);
  // Every grid carries the frame, so each reads back on its own.
  for (size_t i = 1; i < out.size(); ++i)
    for (const char* key : {"nimbus_resolution", "nimbus_bounds_min", "nimbus_bounds_max"})
      out[i]->insertMeta(key, *grid->operator[](key));
  return out;
}

absl::StatusOr<DenseVolume> ToDense(const openvdb::GridPtrVecPtr& grids, const std::string& name) {
  openvdb::FloatGrid::Ptr grid;
  for (const auto& g : *grids)
    if (g->getName() == name) grid = openvdb::gridPtrCast<openvdb::FloatGrid>(g);
  if (!grid) return absl::NotFoundError(absl::StrCat("no float grid named '", name, "'"));
  DenseVolume out;
  out.name = name;
  out.grid_class = openvdb::GridBase::gridClassToString(grid->getGridClass());
  auto res = grid->getMetadata<openvdb::Vec3IMetadata>("nimbus_resolution");
  auto bmin = grid->getMetadata<openvdb::Vec3DMetadata>("nimbus_bounds_min");
  auto bmax = grid->getMetadata<openvdb::Vec3DMetadata>("nimbus_bounds_max");
  if (!res || !bmin || !bmax)
    return absl::InvalidArgumentError("grid lacks nimbus_resolution/bounds metadata");
  const openvdb::Vec3i r = res->value();
  out.frame.resolution = {r.x(), r.y(), r.z()};
  out.frame.bounds = {{bmin->value().x(), bmin->value().y(), bmin->value().z()},
                      {bmax->value().x(), bmax->value().y(), bmax->value().z()}};
  const openvdb::Vec3d o = grid->indexToWorld(openvdb::Vec3d(0, 0, 0));
  const openvdb::Vec3d vs = grid->voxelSize();
  out.origin_center = {o.x(), o.y(), o.z()};
  out.voxel_size = {vs.x(), vs.y(), vs.z()};
  out.values.assign(size_t(r.x()) * r.y() * r.z(), 0.f);
  for (auto it = grid->cbeginValueOn(); it; ++it) {
    const openvdb::Coord c = it.getCoord();
    if (c.x() < 0 || c.y() < 0 || c.z() < 0 || c.x() >= r.x() || c.y() >= r.y() || c.z() >= r.z())
      return absl::DataLossError("active voxel outside the recorded resolution");
    out.values[(size_t(c.x()) * r.y() + c.y()) * r.z() + c.z()] = *it;
  }
  for (auto it = grid->beginMeta(); it != grid->endMeta(); ++it) {
    const auto& m = it->second;
    if (auto s = openvdb::DynamicPtrCast<openvdb::StringMetadata>(m))
      out.metadata.emplace_back(it->first, s->value());
    else if (auto i = openvdb::DynamicPtrCast<openvdb::Int64Metadata>(m))
      out.metadata.emplace_back(it->first, i->value());
    else if (auto d = openvdb::DynamicPtrCast<openvdb::DoubleMetadata>(m))
      out.metadata.emplace_back(it->first, d->value());
  }
  return out;
}

}  // namespace

const MetaValue* DenseVolume::Find(const std::string& key) const {
  for (const auto& [k, v] : metadata)
    if (k == key) return &v;
  return nullptr;
}

absl::Status WriteDensityVdb(const std::filesystem::path& path, const CountGrid& counts,
                             const GridFrame& frame, const DensityOptions& options,
                             const Metadata& metadata) {
  InitOpenVdb();
  openvdb::GridPtrVec grids;
  try {
    grids = BuildGrids(counts, frame, options, metadata);
  } catch (const std::exception& e) {
    return absl::InternalError(
        absl::StrCat("building the grids of ", path.string(), ": ", e.what()));
  }
  return vdb_internal::WriteGridsAtomically(path, grids);
}

absl::StatusOr<std::string> DensityVdbBytes(const CountGrid& counts, const GridFrame& frame,
                                            const DensityOptions& options,
                                            const Metadata& metadata) {
  InitOpenVdb();
  try {
    std::ostringstream os(std::ios_base::binary);
    openvdb::GridPtrVec grids = BuildGrids(counts, frame, options, metadata);
    openvdb::io::Stream stream(os);
    stream.setCompression(openvdb::io::COMPRESS_BLOSC | openvdb::io::COMPRESS_ACTIVE_MASK);
    stream.write(grids);
    std::string bytes = os.str();
    vdb_internal::StampContentUuid(bytes);
    return bytes;
  } catch (const std::exception& e) {
    return absl::InternalError(absl::StrCat("serialising VDB: ", e.what()));
  }
}

absl::StatusOr<DenseVolume> ReadVdbFile(const std::filesystem::path& path,
                                        const std::string& name) {
  InitOpenVdb();
  try {
    auto grids = vdb_internal::ReadAllGrids(path);
    return ToDense(grids, name);
  } catch (const std::exception& e) {
    return absl::InvalidArgumentError(absl::StrCat("reading ", path.string(), ": ", e.what()));
  }
}

absl::StatusOr<DenseVolume> ReadVdbBytes(const std::string& bytes, const std::string& name) {
  InitOpenVdb();
  try {
    std::istringstream is(bytes, std::ios_base::binary);
    openvdb::io::Stream stream(is);
    return ToDense(stream.getGrids(), name);
  } catch (const std::exception& e) {
    return absl::InvalidArgumentError(absl::StrCat("reading VDB bytes: ", e.what()));
  }
}

uint64_t OutputBytesPerVoxel(const DensityOptions& o) {
  uint64_t bytes = sizeof(float);
  if (o.color) bytes += 3 * sizeof(float);
  if (o.address_grid) bytes += sizeof(float);
  if (o.raw_counts == RawCounts::kFloat) bytes += sizeof(float);
  if (o.raw_counts == RawCounts::kInteger) bytes += sizeof(int64_t);
  return bytes;
}

absl::StatusOr<DenseVec3Volume> ReadVec3VdbFile(const std::filesystem::path& path,
                                                const std::string& name) {
  InitOpenVdb();
  try {
    auto grids = vdb_internal::ReadAllGrids(path);
    openvdb::Vec3SGrid::Ptr grid;
    openvdb::GridBase::Ptr any;
    for (const auto& g : *grids) {
      if (g->getName() == name) grid = openvdb::gridPtrCast<openvdb::Vec3SGrid>(g);
      if (!any && g->getMetadata<openvdb::Vec3IMetadata>("nimbus_resolution")) any = g;
    }
    if (!grid) return absl::NotFoundError(absl::StrCat("no Vec3f grid named '", name, "'"));
    if (!any) return absl::InvalidArgumentError("no grid carries nimbus_resolution");
    const openvdb::Vec3i r = any->getMetadata<openvdb::Vec3IMetadata>("nimbus_resolution")->value();
    DenseVec3Volume out;
    out.resolution = {r.x(), r.y(), r.z()};
    const size_t n = size_t(r.x()) * r.y() * r.z();
    out.values.assign(n, Vec3{});
    out.active.assign(n, false);
    for (auto it = grid->cbeginValueOn(); it; ++it) {
      const openvdb::Coord c = it.getCoord();
      if (c.x() < 0 || c.y() < 0 || c.z() < 0 || c.x() >= r.x() || c.y() >= r.y() || c.z() >= r.z())
        return absl::DataLossError("active voxel outside the recorded resolution");
      const size_t i = (size_t(c.x()) * r.y() + c.y()) * r.z() + c.z();
      out.values[i] = {(*it).x(), (*it).y(), (*it).z()};
      out.active[i] = true;
    }
    return out;
  } catch (const std::exception& e) {
    return absl::InvalidArgumentError(absl::StrCat("reading ", path.string(), ": ", e.what()));
  }
}

int DownsampleFactor(Int3 r, int max_resolution) {
  const int largest = std::max({r.x, r.y, r.z});
  if (max_resolution <= 0) return 1;
  return std::max(1, (largest + max_resolution - 1) / max_resolution);
}

GridFrame DownsampleFrame(const GridFrame& frame, int factor) {
  const Int3 r = frame.resolution;
  GridFrame out;
  out.resolution = {(r.x + factor - 1) / factor, (r.y + factor - 1) / factor,
                    (r.z + factor - 1) / factor};
  const Vec3 h = frame.VoxelSize();
  out.bounds.min = frame.bounds.min;
  out.bounds.max =
      frame.bounds.min + Vec3{out.resolution.x * factor * h.x, out.resolution.y * factor * h.y,
                              out.resolution.z * factor * h.z};
  return out;
}

CountGrid DownsampleCounts(const std::vector<const CountGrid*>& parts, int factor) {
  const Int3 r = parts.empty() ? Int3{1, 1, 1} : parts[0]->resolution();
  CountGrid out(
      Int3{(r.x + factor - 1) / factor, (r.y + factor - 1) / factor, (r.z + factor - 1) / factor});
  for (const CountGrid* part : parts) {
    part->ForEachTile([&](Int3 o, const uint32_t* tile) {
      for (uint32_t i = 0; i < uint32_t(CountGrid::kTileVoxels); ++i) {
        if (!tile[i]) continue;
        const Int3 l = CountGrid::LocalCoord(i);
        out.Add((o.x + l.x) / factor, (o.y + l.y) / factor, (o.z + l.z) / factor, tile[i]);
      }
    });
  }
  return out;
}

}  // namespace nimbus
