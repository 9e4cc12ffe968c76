// The OpenVDB side of vdb_io.h: built into the libnimbus_vdb.so module only
// (vdb_module.h), where vdb_module_entry.cc puts these functions in its table.
#include "core/io/vdb_io.h"

#include <openvdb/io/Compression.h>
#include <openvdb/io/Stream.h>
#include <openvdb/openvdb.h>
#include <openvdb/tools/SignedFloodFill.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_invoke.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <memory>
#include <mutex>
#include <sstream>
#include <vector>

#include "absl/strings/str_cat.h"
#include "core/io/metadata_keys.h"
#include "core/io/result_values.h"
#include "core/io/vdb_impl.h"
#include "core/io/vdb_internal.h"

namespace nimbus {

namespace vdb_internal {

void InitOpenVdb() {
  static std::once_flag once;
  std::call_once(once, [] { openvdb::initialize(); });
}

openvdb::math::Transform::Ptr FrameTransform(const GridFrame& frame, UpAxis up) {
  const Vec3 h = frame.VoxelSize();
  openvdb::math::Mat4d m = openvdb::math::Mat4d::identity();
  m.setToScale(openvdb::Vec3d(h.x, h.y, h.z));
  // Index-space voxel centres sit at integer coordinates in OpenVDB.
  m.setTranslation(openvdb::Vec3d(frame.bounds.min.x + 0.5 * h.x, frame.bounds.min.y + 0.5 * h.y,
                                  frame.bounds.min.z + 0.5 * h.z));
  if (up == UpAxis::kZ) {
    // OpenVDB maps row vectors (p * M): these rows send (x, y, z) to
    // (x, -z, y), a right-handed quarter turn about +X taking +Y to +Z.
    openvdb::math::Mat4d r = openvdb::math::Mat4d::identity();
    r.setRow(1, openvdb::Vec4d(0, 0, 1, 0));
    r.setRow(2, openvdb::Vec4d(0, -1, 0, 0));
    m = m * r;
  }
  return openvdb::math::Transform::createLinearTransform(m);
}

const char* UpAxisName(UpAxis up) { return up == UpAxis::kZ ? "Z" : "Y"; }

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

// The archive compression of every Nimbus file.
constexpr uint32_t kArchiveCompression =
    openvdb::io::COMPRESS_BLOSC | openvdb::io::COMPRESS_ACTIVE_MASK;

// OpenVDB's own archive writer (what io::File::write calls), into a stream
// of ours: io::File writes through a std::ofstream it never checks, so a
// full disk would leave a short file that looks whole. Archive's stream
// writer is protected, hence the subclass; it adds nothing else.
class ArchiveWriter : public openvdb::io::Archive {
 public:
  void WriteTo(std::ostream& os, const openvdb::GridPtrVec& grids) const {
    write(os, grids, /*seekable=*/true, openvdb::MetaMap());
  }
};

}  // namespace

absl::Status WriteGridsAtomically(const std::filesystem::path& path,
                                  const openvdb::GridPtrVec& grids) {
  return WriteArchiveAtomically(path, [&](std::ostream& os) {
    ArchiveWriter archive;
    archive.setCompression(kArchiveCompression);
    archive.WriteTo(os, grids);
  });
}

}  // namespace vdb_internal

using vdb_internal::FrameTransform;
using vdb_internal::InitOpenVdb;

namespace {

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

// Scales a leaf's active densities by the modulation at the voxel centres.
template <typename LeafT>
void Modulate(const std::function<double(const Vec3&)>& modulation, const GridFrame& frame,
              LeafT& leaf) {
  for (auto it = leaf.beginValueOn(); it; ++it) {
    const openvdb::Coord c = it.getCoord();
    const double m = modulation(frame.VoxelCenter({c.x(), c.y(), c.z()}));
    it.setValue(float(double(*it) * std::max(0.0, m)));
  }
}

// The grids of one result before the conventions: the density plus the
// optional Cd / address / counts grids, all on the same active voxels.
struct ResultGrids {
  openvdb::FloatGrid::Ptr density, addr, raw_f;
  openvdb::Vec3SGrid::Ptr cd;
  openvdb::Int64Grid::Ptr raw_i;
};

// A grid's leaves built apart from its tree (on any thread), added later.
template <typename LeafT>
using LeafBatch = std::vector<std::unique_ptr<LeafT>>;
using FloatLeaf = openvdb::FloatTree::LeafNodeType;

// Through an accessor: leaves that follow each other mostly share their
// parent nodes, whose lookups it caches.
template <typename GridT>
void AddLeaves(LeafBatch<typename GridT::TreeType::LeafNodeType>& leaves, GridT& grid) {
  auto acc = grid.getAccessor();
  for (auto& leaf : leaves) acc.addLeaf(leaf.release());
  leaves.clear();
  leaves.shrink_to_fit();
}

// The leaves of one chunk of count tiles, one batch per grid of a result.
struct ResultLeaves {
  LeafBatch<FloatLeaf> density, addr, raw_f;
  LeafBatch<openvdb::Vec3STree::LeafNodeType> cd;
  LeafBatch<openvdb::Int64Tree::LeafNodeType> raw_i;
};

// Makes the leaves of every grid of a result at one 8^3 leaf of counts.
struct ResultLeafMaker {
  const DensityOptions& options;
  const GridFrame& frame;
  const Normaliser& norm;
  bool color, address, raw_f, raw_i;

  // A leaf at `c` whose voxels with a count are active, set to value(i).
  // (Straight into the leaf's buffer and mask: setValueOn checks each
  // voxel for out-of-core data, which a new leaf never has.)
  template <typename LeafT, typename Value>
  static void Add(LeafBatch<LeafT>& to, const openvdb::Coord& c, const uint32_t* v,
                  const Value& value) {
    auto leaf = std::make_unique<LeafT>(c, openvdb::zeroVal<typename LeafT::ValueType>());
    typename LeafT::ValueType* data = leaf->buffer().data();
    typename LeafT::NodeMaskType mask;
    for (int i = 0; i < 512; ++i)
      if (v[i]) data[i] = value(i), mask.setOn(i);
    leaf->setValueMask(mask);
    to.push_back(std::move(leaf));
  }

  // The Cd leaf: the palette's colours of the voxels with a count, in one
  // batch (EvalFloats: float(Eval) bit for bit).
  template <typename CoordFn>
  void AddColors(LeafBatch<openvdb::Vec3STree::LeafNodeType>& to, const openvdb::Coord& c,
                 const uint32_t* v, const CoordFn& coord) const {
    double t[512];
    std::array<float, 3> rgb[512];
    int n = 0;
    for (int i = 0; i < 512; ++i)
      if (v[i]) t[n++] = coord(i);
    options.palette.EvalFloats(t, size_t(n), rgb);
    int k = 0;
    Add(to, c, v, [&](int) {
      const std::array<float, 3>& f = rgb[k++];
      return openvdb::Vec3s(f[0], f[1], f[2]);
    });
  }

  void operator()(Int3 o, const uint32_t* v, const uint64_t* cs, ResultLeaves& out) const {
    const openvdb::Coord c(o.x, o.y, o.z);
    Add(out.density, c, v, [&](int i) { return norm(v[i]); });
    if (options.modulation) Modulate(options.modulation, frame, *out.density.back());
    // The mean colour coordinate of a voxel's visits.
    const double inv_scale = 1.0 / CountGrid::kColorScale;
    auto coord = [&](int i) { return double(cs[i]) * inv_scale / double(v[i]); };
    if (color) AddColors(out.cd, c, v, coord);
    if (address) Add(out.addr, c, v, [&](int i) { return float(coord(i)); });
    if (raw_f) Add(out.raw_f, c, v, [&](int i) { return float(v[i]); });
    if (raw_i) Add(out.raw_i, c, v, [&](int i) { return int64_t(v[i]); });
  }
};

// Built straight from the count tiles, in the spec's frame: the leaves of
// each chunk of tiles in parallel, then added to the trees (a tree does not
// depend on the order its leaves come in).
ResultGrids BuildFineGrids(const CountGrid& counts, uint32_t max_count, const GridFrame& frame,
                           const DensityOptions& options, bool int64_counts) {
  ResultGrids g;
  g.density = NewGrid<openvdb::FloatGrid>(options.grid_name, frame, openvdb::GRID_FOG_VOLUME);
  const bool color = options.color && counts.has_color();
  const bool address = options.address_grid && counts.has_color();
  if (color) g.cd = NewGrid<openvdb::Vec3SGrid>("Cd", frame, openvdb::GRID_UNKNOWN);
  if (address) g.addr = NewGrid<openvdb::FloatGrid>("address", frame, openvdb::GRID_UNKNOWN);
  // The result always carries float counts (every reader opens them); the
  // exact integer counts go to a file of their own (WriteIntegerCountsVdb).
  if (options.raw_counts != RawCounts::kNone && !int64_counts)
    g.raw_f = NewGrid<openvdb::FloatGrid>("counts", frame, openvdb::GRID_UNKNOWN);
  if (int64_counts) g.raw_i = NewGrid<openvdb::Int64Grid>("counts", frame, openvdb::GRID_UNKNOWN);
  const Normaliser norm(options, max_count);
  const ResultLeafMaker make{options, frame, norm, color, address, bool(g.raw_f), bool(g.raw_i)};
  constexpr size_t kTilesPerTask = 4;
  const size_t tiles = counts.TileCount();
  std::vector<ResultLeaves> chunks((tiles + kTilesPerTask - 1) / kTilesPerTask);
  tbb::parallel_for(size_t{0}, chunks.size(), [&](size_t k) {
    counts.ForEachLeafInTiles(k * kTilesPerTask, std::min(tiles, (k + 1) * kTilesPerTask),
                              [&](Int3 o, const uint32_t* v, const uint64_t* cs) {
                                make(o, v, cs, chunks[k]);
                              });
  });
  // Each tree takes its leaves on a thread of its own, chunk by chunk.
  auto add_all = [&chunks](auto member, auto& grid) {
    if (grid)
      for (ResultLeaves& chunk : chunks) AddLeaves(chunk.*member, *grid);
  };
  tbb::parallel_invoke([&] { add_all(&ResultLeaves::density, g.density); },
                       [&] { add_all(&ResultLeaves::cd, g.cd); },
                       [&] { add_all(&ResultLeaves::addr, g.addr); },
                       [&] { add_all(&ResultLeaves::raw_f, g.raw_f); },
                       [&] { add_all(&ResultLeaves::raw_i, g.raw_i); });
  return g;
}

openvdb::Coord CoarseCoord(const openvdb::Coord& c, int f) {
  // Voxels have non-negative coordinates, so division floors.
  return openvdb::Coord(c.x() / f, c.y() / f, c.z() / f);
}

// Box filter: each coarse voxel gets the sum of its f^3 block times `scale`.
template <typename GridT>
typename GridT::Ptr CoarsenSum(const GridT& fine, int f, double scale) {
  using V = typename GridT::ValueType;
  auto out = GridT::create();
  out->setName(fine.getName());
  out->setGridClass(fine.getGridClass());
  auto acc = out->getAccessor();
  for (auto it = fine.cbeginValueOn(); it; ++it) {
    const openvdb::Coord cc = CoarseCoord(it.getCoord(), f);
    acc.setValueOn(cc, V(acc.getValue(cc) + *it));
  }
  if (scale != 1.0)
    for (auto it = out->beginValueOn(); it; ++it) it.setValue(V(*it * scale));
  return out;
}

// Density-weighted mean over each block: colours and addresses of the
// voxels that carry the mass.
template <typename GridT>
typename GridT::Ptr CoarsenWeighted(const GridT& fine, const openvdb::FloatGrid& weight, int f) {
  using V = typename GridT::ValueType;
  auto out = GridT::create();
  out->setName(fine.getName());
  out->setGridClass(fine.getGridClass());
  auto wsum = openvdb::FloatGrid::create();
  auto acc = out->getAccessor();
  auto wacc = wsum->getAccessor();
  auto win = weight.getConstAccessor();
  for (auto it = fine.cbeginValueOn(); it; ++it) {
    const float w = win.getValue(it.getCoord());
    const openvdb::Coord cc = CoarseCoord(it.getCoord(), f);
    acc.setValueOn(cc, V(acc.getValue(cc) + *it * w));
    wacc.setValueOn(cc, wacc.getValue(cc) + w);
  }
  for (auto it = out->beginValueOn(); it; ++it) {
    const float w = wacc.getValue(it.getCoord());
    it.setValue(w > 0 ? V(*it * (1.0f / w)) : V(*it));
  }
  return out;
}

ResultGrids Coarsen(const ResultGrids& g, int f) {
  ResultGrids out;
  // Mean density: density times voxel volume keeps its sum.
  out.density = CoarsenSum(*g.density, f, 1.0 / (double(f) * f * f));
  if (g.cd) out.cd = CoarsenWeighted(*g.cd, *g.density, f);
  if (g.addr) out.addr = CoarsenWeighted(*g.addr, *g.density, f);
  if (g.raw_f) out.raw_f = CoarsenSum(*g.raw_f, f, 1.0);
  if (g.raw_i) out.raw_i = CoarsenSum(*g.raw_i, f, 1.0);
  return out;
}

// nimbus_suggested_density from the written density grid.
// The sum runs in the order of the grid's value iterator (leaves in tree
// order, voxels by offset), so the same grid always gives the same double;
// a grid with active tiles takes the iterator itself.
double SuggestedDensityOf(const openvdb::FloatGrid& grid) {
  const uint64_t n = grid.activeVoxelCount();
  double sum = 0;
  if (grid.tree().activeTileCount() == 0) {
    for (auto leaf = grid.tree().cbeginLeaf(); leaf; ++leaf) {
      const float* values = leaf->buffer().data();
      for (auto on = leaf->getValueMask().beginOn(); on; ++on) sum += values[on.pos()];
    }
  } else {
    for (auto it = grid.cbeginValueOn(); it; ++it) sum += *it;
  }
  const openvdb::Vec3d h = grid.voxelSize();
  return SuggestedDensity(n, n ? sum / double(n) : 0.0, std::cbrt(h.x() * h.y() * h.z()));
}

// The counts' largest and total, which every result grid records.
void AddCountMeta(openvdb::MetaMap& meta, const CountGrid::Sums& sums) {
  meta.insertMeta("nimbus_max_count", openvdb::Int64Metadata(int64_t(sums.max)));
  meta.insertMeta("nimbus_total_count", openvdb::Int64Metadata(int64_t(sums.total)));
}

// The conventions every grid shares: transform, frame and convention
// metadata, half floats.
void FinishGrid(openvdb::GridBase& grid, const GridFrame& frame, const OutputConventions& c,
                int factor) {
  grid.setTransform(vdb_internal::FrameTransform(frame, c.up_axis));
  vdb_internal::SetFrameMetadata(grid, frame);
  grid.insertMeta(meta_key::kUpAxis, openvdb::StringMetadata(vdb_internal::UpAxisName(c.up_axis)));
  grid.insertMeta(meta_key::kDownsampleFactor, openvdb::Int64Metadata(factor));
  grid.setSaveFloatAsHalf(c.half_float);
}

openvdb::GridPtrVec BuildGrids(const CountGrid& counts, const GridFrame& fine_frame,
                               const DensityOptions& options, const Metadata& metadata,
                               bool int64_counts = false) {
  const CountGrid::Sums sums = counts.MaxAndTotal();
  ResultGrids g = BuildFineGrids(counts, sums.max, fine_frame, options, int64_counts);
  const int factor = OutputDownsampleFactor(counts, options);
  GridFrame frame = fine_frame;
  if (factor > 1) {
    g = Coarsen(g, factor);
    frame = DownsampleFrame(fine_frame, factor);
  }
  openvdb::GridPtrVec out{g.density};
  if (g.cd) out.push_back(g.cd);
  if (g.addr) out.push_back(g.addr);
  if (g.raw_f) out.push_back(g.raw_f);
  if (g.raw_i) out.push_back(g.raw_i);
  // Every grid carries the frame and conventions, so each reads back alone.
  for (auto& grid : out) FinishGrid(*grid, frame, options.conventions, factor);
  auto& grid = *g.density;
  AddCountMeta(grid, sums);
  grid.insertMeta("nimbus_density_mapping", openvdb::StringMetadata(MappingName(options.mapping)));
  if (options.mapping == DensityMapping::kGamma)
    grid.insertMeta("nimbus_density_gamma", openvdb::DoubleMetadata(options.gamma));
  if (g.cd)
    grid.insertMeta("nimbus_palette",
                    openvdb::StringMetadata(options.palette.is_sine() ? "sine" : "stops"));
  grid.insertMeta(meta_key::kSuggestedDensity, openvdb::DoubleMetadata(SuggestedDensityOf(grid)));
  for (const auto& [k, v] : metadata) AddMeta(grid, k, v);
  return out;
}

// Calls f(offset, value) for every voxel of the 8^3 leaf at `o` inside
// the volume, offset in LeafNode order.
template <typename F>
void ForEachLeafVoxel(const FloatVolume& volume, const openvdb::Coord& o, F&& f) {
  const Int3 r = volume.frame.resolution;
  const int nx = std::min(8, r.x - o.x()), ny = std::min(8, r.y - o.y()),
            nz = std::min(8, r.z - o.z());
  for (int i = 0; i < nx; ++i)
    for (int j = 0; j < ny; ++j) {
      const float* row = &volume.values[(size_t(o.x() + i) * r.y + (o.y() + j)) * r.z + o.z()];
      for (int k = 0; k < nz; ++k) f((i << 6) | (j << 3) | k, row[k]);
    }
}

// A fog volume's grid (non-zero voxels active), its leaves built in
// parallel, one slab of leaves per task.
openvdb::FloatGrid::Ptr BuildFogVolume(const FloatVolume& volume) {
  auto grid =
      NewGrid<openvdb::FloatGrid>(volume.grid_name, volume.frame, openvdb::GRID_FOG_VOLUME);
  const Int3 r = volume.frame.resolution;
  std::vector<LeafBatch<FloatLeaf>> slabs(size_t(r.x + 7) / 8);
  tbb::parallel_for(size_t{0}, slabs.size(), [&](size_t s) {
    for (int y = 0; y < r.y; y += 8)
      for (int z = 0; z < r.z; z += 8) {
        auto leaf = std::make_unique<FloatLeaf>(openvdb::Coord(int(8 * s), y, z), 0.f);
        ForEachLeafVoxel(volume, leaf->origin(), [&](int i, float v) {
          if (v != 0.f) leaf->setValueOn(i, v);
        });
        if (!leaf->isEmpty()) slabs[s].push_back(std::move(leaf));
      }
  });
  for (auto& slab : slabs) AddLeaves(slab, *grid);
  return grid;
}

// A level set's grid: values with |v| < background active, the rest
// ±background by sign (signed flood fill).
openvdb::FloatGrid::Ptr BuildLevelSet(const FloatVolume& volume) {
  auto grid = NewGrid<openvdb::FloatGrid>(volume.grid_name, volume.frame, openvdb::GRID_LEVEL_SET);
  grid->tree().root().setBackground(volume.background, false);
  auto acc = grid->getAccessor();
  const Int3 r = volume.frame.resolution;
  size_t i = 0;
  for (int x = 0; x < r.x; ++x)
    for (int y = 0; y < r.y; ++y)
      for (int z = 0; z < r.z; ++z, ++i) {
        const float v = volume.values[i];
        if (std::abs(v) < volume.background) acc.setValue(openvdb::Coord(x, y, z), v);
      }
  openvdb::tools::signedFloodFill(grid->tree());
  return grid;
}

// Vectors are world-space quantities: a Z-up file turns them with the grid.
openvdb::Vec3SGrid::Ptr BuildVec3Grid(const Vec3Field& field, const GridFrame& frame,
                                     const OutputConventions& conventions) {
  auto grid = NewGrid<openvdb::Vec3SGrid>(field.name, frame, openvdb::GRID_UNKNOWN);
  grid->setVectorType(openvdb::VEC_CONTRAVARIANT_RELATIVE);
  const bool z_up = conventions.up_axis == UpAxis::kZ;
  auto acc = grid->getAccessor();
  for (const auto& [c, v] : field.voxels) {
    const openvdb::Vec3s w = z_up ? openvdb::Vec3s(float(v.x), float(-v.z), float(v.y))
                                  : openvdb::Vec3s(float(v.x), float(v.y), float(v.z));
    acc.setValueOn(openvdb::Coord(c.x, c.y, c.z), w);
  }
  FinishGrid(*grid, frame, conventions, 1);
  return grid;
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
  for (int col = 0; col < 3; ++col) {
    openvdb::Vec3d e(0, 0, 0);
    e[col] = 1;
    const openvdb::Vec3d w = grid->indexToWorld(e) - o;
    for (int row = 0; row < 3; ++row) out.index_to_world.m[row][col] = w[row];
  }
  for (int row = 0; row < 3; ++row) out.index_to_world.m[row][3] = o[row];
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

// The options a result's exact counts are written with: its conventions
// (so both files share the downsampling factor), without its other grids.
DensityOptions IntegerCountsOptions(const DensityOptions& options) {
  DensityOptions o = options;
  o.color = o.address_grid = false;
  o.raw_counts = RawCounts::kInteger;
  return o;
}

}  // namespace

// The OpenVDB side of vdb_io.h, reached through the module table
// (vdb_module_entry.cc): the names in namespace nimbus are the forwarders.
namespace vdb_impl {

absl::Status WriteDensityVdb(const std::filesystem::path& path, const CountGrid& counts,
                             const GridFrame& frame, const DensityOptions& options,
                             const Metadata& metadata, const std::vector<Vec3Field>& fields) {
  InitOpenVdb();
  openvdb::GridPtrVec grids;
  try {
    grids = BuildGrids(counts, frame, options, metadata);
    // The converter refuses downsampling when vector fields are written.
    for (const Vec3Field& f : fields)
      grids.push_back(BuildVec3Grid(f, frame, options.conventions));
  } catch (const std::exception& e) {
    return absl::InternalError(
        absl::StrCat("building the grids of ", path.string(), ": ", e.what()));
  }
  return vdb_internal::WriteGridsAtomically(path, grids);
}

absl::Status WriteFloatVolumeVdb(const std::filesystem::path& path, const FloatVolume& volume,
                                 const Metadata& metadata, const OutputConventions& conventions) {
  InitOpenVdb();
  const Int3 r = volume.frame.resolution;
  if (volume.values.size() != size_t(r.Volume()))
    return absl::InvalidArgumentError(absl::StrCat("float volume: ", volume.values.size(),
                                                   " values for ", r.Volume(), " voxels"));
  openvdb::GridPtrVec grids;
  try {
    auto grid = volume.level_set ? BuildLevelSet(volume) : BuildFogVolume(volume);
    FinishGrid(*grid, volume.frame, conventions, 1);
    for (const auto& [k, v] : metadata) AddMeta(*grid, k, v);
    grids.push_back(grid);
  } catch (const std::exception& e) {
    return absl::InternalError(absl::StrCat("building the grid of ", path.string(), ": ", e.what()));
  }
  return vdb_internal::WriteGridsAtomically(path, grids);
}

absl::Status WriteIntegerCountsVdb(const std::filesystem::path& path, const CountGrid& counts,
                                   const GridFrame& frame, const DensityOptions& options,
                                   const Metadata& metadata) {
  InitOpenVdb();
  const DensityOptions o = IntegerCountsOptions(options);
  openvdb::GridPtrVec grids;
  try {
    grids = BuildGrids(counts, frame, o, metadata, true);
    grids.erase(grids.begin());  // the density grid lives in the result
    AddCountMeta(*grids[0], counts.MaxAndTotal());
    for (const auto& [k, v] : metadata) AddMeta(*grids[0], k, v);
  } catch (const std::exception& e) {
    return absl::InternalError(absl::StrCat("building the counts grid of ", path.string(), ": ",
                                            e.what()));
  }
  return vdb_internal::WriteGridsAtomically(path, grids);
}


absl::StatusOr<std::vector<int64_t>> ReadIntegerCountsVdb(const std::filesystem::path& path,
                                                          Int3 resolution) {
  InitOpenVdb();
  std::vector<int64_t> out(size_t(resolution.Volume()), 0);
  try {
    const openvdb::GridPtrVecPtr grids = vdb_internal::ReadAllGrids(path);
    for (const auto& g : *grids) {
      auto grid = openvdb::gridPtrCast<openvdb::Int64Grid>(g);
      if (g->getName() != "counts" || !grid) continue;
      for (auto it = grid->cbeginValueOn(); it; ++it) {
        const openvdb::Coord c = it.getCoord();
        if (c.x() < 0 || c.y() < 0 || c.z() < 0 || c.x() >= resolution.x ||
            c.y() >= resolution.y || c.z() >= resolution.z)
          return absl::DataLossError(absl::StrCat(path.string(), ": a count outside the grid"));
        out[(size_t(c.x()) * resolution.y + c.y()) * resolution.z + c.z()] = *it;
      }
      return out;
    }
  } catch (const std::exception& e) {
    return absl::DataLossError(absl::StrCat(path.string(), ": ", e.what()));
  }
  return absl::NotFoundError(absl::StrCat(path.string(), ": no Int64 grid named 'counts'"));
}

absl::StatusOr<std::string> DensityVdbBytes(const CountGrid& counts, const GridFrame& frame,
                                            const DensityOptions& options,
                                            const Metadata& metadata) {
  InitOpenVdb();
  try {
    std::ostringstream os(std::ios_base::binary);
    openvdb::GridPtrVec grids = BuildGrids(counts, frame, options, metadata);
    openvdb::io::Stream stream(os);
    stream.setCompression(vdb_internal::kArchiveCompression);
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

}  // namespace vdb_impl

}  // namespace nimbus