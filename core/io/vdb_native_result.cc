#include "core/io/vdb_native_result.h"

#include <tbb/parallel_for.h>

#include <bit>
#include <cmath>
#include <cstring>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <utility>

#include "absl/strings/str_cat.h"
#include "core/io/metadata_keys.h"
#include "core/io/result_values.h"
#include "core/io/vdb_file.h"
#include "core/io/vdb_native.h"

namespace nimbus::vdb_native {

namespace {

// vdb_internal::FrameTransform without OpenVDB: voxel centres at integer
// index coordinates, and for Z up the quarter turn (x, y, z) -> (x, -z, y)
// multiplied in as Mat4d::operator* sums it.
LinearTransform FrameTransform(const GridFrame& frame, UpAxis up) {
  const Vec3 h = frame.VoxelSize();
  LinearTransform t{};
  for (int i = 0; i < 4; ++i) t.m[i][i] = 1;
  t.m[0][0] = h.x, t.m[1][1] = h.y, t.m[2][2] = h.z;
  t.m[3][0] = frame.bounds.min.x + 0.5 * h.x;
  t.m[3][1] = frame.bounds.min.y + 0.5 * h.y;
  t.m[3][2] = frame.bounds.min.z + 0.5 * h.z;
  if (up != UpAxis::kZ) return t;
  const double r[4][4] = {{1, 0, 0, 0}, {0, 0, 1, 0}, {0, -1, 0, 0}, {0, 0, 0, 1}};
  LinearTransform out{};
  for (int i = 0; i < 4; ++i)
    for (int j = 0; j < 4; ++j)
      out.m[i][j] = t.m[i][0] * r[0][j] + t.m[i][1] * r[1][j] + t.m[i][2] * r[2][j] +
                    t.m[i][3] * r[3][j];
  return out;
}

void AddMeta(MetaMap& meta, const std::string& key, const MetaValue& v) {
  if (auto* s = std::get_if<std::string>(&v)) meta.String(key, *s);
  if (auto* i = std::get_if<int64_t>(&v)) meta.Int64(key, *i);
  if (auto* d = std::get_if<double>(&v)) meta.Double(key, *d);
}

// A folded (2D) grid's leaves: counted per range of tiles first, then
// written straight into one list at each range's offset. Per-range lists
// faulted in some 300 fresh heap pages for a 1024^2 picture (about 12 us
// each in a virtual machine), and were copied again to join them.
std::shared_ptr<LeafList> FoldedLeaves(const CountGrid& counts, size_t per_range) {
  const size_t ranges = (counts.TileCount() + per_range - 1) / per_range;
  auto tiles = [&](size_t r) {
    return std::pair{r * per_range, std::min(counts.TileCount(), (r + 1) * per_range)};
  };
  std::vector<size_t> first(ranges + 1, 0);
  tbb::parallel_for(size_t{0}, ranges, [&](size_t r) {
    const auto [begin, end] = tiles(r);
    counts.ForEachLeafMaskInTiles(begin, end, [&](Int3, const uint64_t*) { ++first[r + 1]; });
  });
  for (size_t r = 0; r < ranges; ++r) first[r + 1] += first[r];
  auto leaves = std::make_shared<LeafList>(first[ranges]);
  tbb::parallel_for(size_t{0}, ranges, [&](size_t r) {
    const auto [begin, end] = tiles(r);
    Leaf* out = leaves->data() + first[r];
    counts.ForEachLeafMaskInTiles(begin, end, [&](Int3 o, const uint64_t* mask) {
      *out = Leaf{{o.x, o.y, o.z}, {}};
      std::copy(mask, mask + 8, out->mask.begin());
      ++out;
    });
  });
  return leaves;
}

// The counts' leaves in tree order, each active where counted. Tiles are
// scanned in parallel; a 3D grid's ranges each into its own list (its tile
// table counts every tile, allocated or not), joined in tile order.
std::shared_ptr<const LeafList> CountLeaves(const CountGrid& counts) {
  constexpr size_t kTilesPerRange = 16;
  std::shared_ptr<LeafList> leaves;
  if (counts.folded()) {
    leaves = FoldedLeaves(counts, kTilesPerRange);
  } else {
    const size_t ranges = (counts.TileCount() + kTilesPerRange - 1) / kTilesPerRange;
    std::vector<std::vector<Leaf>> parts(ranges);
    tbb::parallel_for(size_t{0}, ranges, [&](size_t r) {
      const size_t end = std::min(counts.TileCount(), (r + 1) * kTilesPerRange);
      counts.ForEachLeafMaskInTiles(r * kTilesPerRange, end, [&](Int3 o, const uint64_t* mask) {
        Leaf leaf{{o.x, o.y, o.z}, {}};
        std::copy(mask, mask + 8, leaf.mask.begin());
        parts[r].push_back(leaf);
      });
    });
    leaves = std::make_shared<LeafList>();
    size_t total = 0;
    for (const auto& p : parts) total += p.size();
    leaves->reserve(total);
    for (const auto& p : parts) leaves->insert(leaves->end(), p.begin(), p.end());
  }
  SortTreeOrder(*leaves);
  return leaves;
}

template <typename F>
void ForEachActive(const Leaf& leaf, F&& f) {
  for (size_t w = 0; w < 8; ++w)
    for (uint64_t bits = leaf.mask[w]; bits; bits &= bits - 1)
      f(int(w * 64 + size_t(std::countr_zero(bits))));
}

// A result's grids as the module's StreamedResult makes them.
struct Result : CountedResult {
  const GridFrame& frame;
  std::shared_ptr<const LeafList> leaves;  // shared by every grid

  Result(const CountGrid& c, const GridFrame& f, const DensityOptions& o, const Metadata& m)
      : CountedResult(c, o, m), frame(f), leaves(CountLeaves(c)) {}

  // An empty grid of the result: NewGrid's name and class plus FinishGrid's
  // conventions (transform, frame, up axis, factor 1, half floats).
  Grid Base(const std::string& name, const char* grid_class, ValueKind kind) const {
    return Conventions(frame, options.conventions, name, grid_class, kind);
  }
  static Grid Conventions(const GridFrame& frame, const OutputConventions& c,
                          const std::string& name, const char* grid_class, ValueKind kind) {
    Grid g;
    g.name = name, g.kind = kind, g.half = c.half_float;
    g.meta.String("name", name);
    g.meta.String("class", grid_class);
    g.transform = FrameTransform(frame, c.up_axis);
    const Int3 r = frame.resolution;
    const Bounds& b = frame.bounds;
    g.meta.Vec3i("nimbus_resolution", r.x, r.y, r.z);
    g.meta.Vec3d("nimbus_bounds_min", b.min.x, b.min.y, b.min.z);
    g.meta.Vec3d("nimbus_bounds_max", b.max.x, b.max.y, b.max.z);
    g.meta.String(meta_key::kUpAxis, c.up_axis == UpAxis::kZ ? "Z" : "Y");
    g.meta.Int64(meta_key::kDownsampleFactor, 1);
    g.meta.Bool("is_saved_as_half_float", c.half_float);
    return g;
  }

  // A voxel's mean colour coordinate from its count and colour sum.
  static double ColorCoord(uint32_t c, uint64_t cs) {
    return double(cs) * (1.0 / CountGrid::kColorScale) / double(c);
  }

  using Visit = std::function<void(const Leaf&, const void*, size_t)>;

  // Encodes `g` on the counts' leaves, a leaf at a time: fill(leaf, n, at,
  // counts, colour sums or null, out) writes the values of the leaf's n
  // active voxels (indices `at`, with their counts and sums) packed into
  // `out`; visit sees each leaf's values in tree order.
  template <typename T, typename Fill>
  void EncodeLeafwise(Grid& g, bool colors, const Fill& fill,
                      const Visit& visit = [](const Leaf&, const void*, size_t) {}) const {
    g.leaves = leaves;
    EncodeLeaves(
        g,
        [&](const Leaf& leaf, void* packed) {
          uint16_t at[512];
          uint32_t v[512];
          uint64_t cs[512];
          const size_t n =
              GatherActiveCounts(counts, {leaf.origin[0], leaf.origin[1], leaf.origin[2]},
                                 leaf.mask.data(), at, v, colors ? cs : nullptr);
          fill(leaf, n, at, v, colors ? cs : nullptr, static_cast<T*>(packed));
        },
        visit);
  }

  // The same with value(leaf, index, count, colour sum) at each counted voxel.
  template <typename T, typename Value>
  void Encode(Grid& g, bool colors, const Value& value,
              const Visit& visit = [](const Leaf&, const void*, size_t) {}) const {
    EncodeLeafwise<T>(
        g, colors,
        [&](const Leaf& leaf, size_t n, const uint16_t* at, const uint32_t* v, const uint64_t* cs,
            T* out) {
          for (size_t k = 0; k < n; ++k) out[k] = value(leaf, at[k], v[k], cs ? cs[k] : 0);
        },
        visit);
  }

  // Cd: each leaf's colour coordinates through the palette in one batch.
  void EncodeColors(Grid& g) const {
    using Rgb = std::array<float, 3>;
    EncodeLeafwise<Rgb>(g, true,
                        [&](const Leaf&, size_t n, const uint16_t*, const uint32_t* v,
                            const uint64_t* cs, Rgb* out) {
                          double t[512];
                          for (size_t k = 0; k < n; ++k) t[k] = ColorCoord(v[k], cs[k]);
                          options.palette.EvalFloats(t, n, out);
                        });
  }

  float Density(const Leaf& leaf, int i, uint32_t c) const {
    const float d = norm(c);
    if (!options.modulation) return d;
    const Int3 p{leaf.origin[0] + (i >> 6), leaf.origin[1] + ((i >> 3) & 7),
                 leaf.origin[2] + (i & 7)};
    const double m = options.modulation(frame.VoxelCenter(p));
    return float(double(d) * std::max(0.0, m));
  }

  Grid DensityGrid() const;
  std::vector<GridSource> Sources(bool int64_counts) const;
};

Grid Result::DensityGrid() const {
  Grid g = Base(options.grid_name, "fog volume", ValueKind::kFloat);
  // nimbus_suggested_density sums the written densities in tree order.
  double sum = 0;
  Encode<float>(
      g, false, [&](const Leaf& leaf, int i, uint32_t c, uint64_t) { return Density(leaf, i, c); },
      [&](const Leaf&, const void* values, size_t n) {
        const float* f = static_cast<const float*>(values);
        for (size_t k = 0; k < n; ++k) sum += f[k];
      });
  g.meta.Int64("nimbus_max_count", int64_t(sums.max));
  g.meta.Int64("nimbus_total_count", int64_t(sums.total));
  g.meta.String("nimbus_density_mapping", MappingName(options.mapping));
  if (options.mapping == DensityMapping::kGamma)
    g.meta.Double("nimbus_density_gamma", options.gamma);
  if (color) g.meta.String("nimbus_palette", options.palette.is_sine() ? "sine" : "stops");
  const uint64_t n = g.active_voxels;
  const std::array<double, 3> h = g.transform.VoxelSize();
  g.meta.Double(meta_key::kSuggestedDensity,
                SuggestedDensity(n, n ? sum / double(n) : 0.0, std::cbrt(h[0] * h[1] * h[2])));
  for (const auto& [k, v] : metadata) AddMeta(g.meta, k, v);
  return g;
}

std::vector<GridSource> Result::Sources(bool int64_counts) const {
  std::vector<GridSource> out;
  if (int64_counts) {
    out.push_back({"counts", [this] {
      Grid g = Base("counts", "unknown", ValueKind::kInt64);
      g.meta.Int64("nimbus_max_count", int64_t(sums.max));
      g.meta.Int64("nimbus_total_count", int64_t(sums.total));
      for (const auto& [k, v] : metadata) AddMeta(g.meta, k, v);
      Encode<int64_t>(g, false, [](const Leaf&, int, uint32_t c, uint64_t) { return int64_t(c); });
      return g;
    }});
    return out;
  }
  out.push_back({options.grid_name, [this] { return DensityGrid(); }});
  if (color)
    out.push_back({"Cd", [this] {
      Grid g = Base("Cd", "unknown", ValueKind::kVec3f);
      EncodeColors(g);
      return g;
    }});
  if (options.address_grid && counts.has_color())
    out.push_back({"address", [this] {
      Grid g = Base("address", "unknown", ValueKind::kFloat);
      Encode<float>(g, true, [&](const Leaf&, int, uint32_t c, uint64_t cs) {
        return float(ColorCoord(c, cs));
      });
      return g;
    }});
  if (options.raw_counts != RawCounts::kNone)
    out.push_back({"counts", [this] {
      Grid g = Base("counts", "unknown", ValueKind::kFloat);
      Encode<float>(g, false, [](const Leaf&, int, uint32_t c, uint64_t) { return float(c); });
      return g;
    }});
  return out;
}

// BuildVec3Grid's grid: the field's vectors (turned with a Z-up file) on
// its voxels, the last value of a repeated voxel winning.
Grid FieldGrid(const Vec3Field& field, const GridFrame& frame, const OutputConventions& c) {
  Grid g = Result::Conventions(frame, c, field.name, "unknown", ValueKind::kVec3f);
  g.meta.String("vector_type", "contravariant relative");
  const bool z_up = c.up_axis == UpAxis::kZ;
  using Values = std::array<std::array<float, 3>, 512>;
  std::map<std::array<int32_t, 3>, std::pair<LeafMask, Values>> by_leaf;
  for (const auto& [p, v] : field.voxels) {
    auto& [mask, values] = by_leaf[{p.x & ~7, p.y & ~7, p.z & ~7}];
    const int i = ((p.x & 7) << 6) | ((p.y & 7) << 3) | (p.z & 7);
    mask[size_t(i >> 6)] |= uint64_t{1} << (i & 63);
    values[size_t(i)] = z_up ? std::array<float, 3>{float(v.x), float(-v.z), float(v.y)}
                             : std::array<float, 3>{float(v.x), float(v.y), float(v.z)};
  }
  auto leaves = std::make_shared<LeafList>();
  for (const auto& [origin, entry] : by_leaf) leaves->push_back({origin, entry.first});
  SortTreeOrder(*leaves);
  g.leaves = std::move(leaves);
  EncodeLeaves(
      g,
      [&](const Leaf& leaf, void* packed) {
        const Values& values = by_leaf.at(leaf.origin).second;
        auto* out = static_cast<std::array<float, 3>*>(packed);
        ForEachActive(leaf, [&](int i) { *out++ = values[size_t(i)]; });
      },
      [](const Leaf&, const void*, size_t) {});
  return g;
}

absl::Status WriteResult(const std::filesystem::path& path, const std::vector<GridSource>& grids) {
  // Large grids' encoded leaves wait on the result's own disk, not in RAM
  // (unless the caller named another place).
  std::optional<vdb_internal::SpillScope> spill;
  if (vdb_internal::SpillScope::Current() == nullptr)
    spill.emplace(path.parent_path().empty() ? "." : path.parent_path(),
                  vdb_internal::kSpillKeepBytes);
  return vdb_internal::WriteArchiveAtomically(
      path, [&](std::ostream& os) { WriteArchive(os, grids); });
}

}  // namespace

bool CanWriteResult(const CountGrid& counts, const DensityOptions& options,
                    const std::vector<Vec3Field>& fields) {
  for (const Vec3Field& f : fields)
    for (const auto& [p, v] : f.voxels)
      if (p.x < 0 || p.y < 0 || p.z < 0) return false;
  return OutputDownsampleFactor(counts, options) == 1;
}

DensityOptions IntegerCountsOptions(const DensityOptions& options) {
  DensityOptions o = options;
  o.color = o.address_grid = false;
  o.raw_counts = RawCounts::kInteger;
  return o;
}

absl::Status WriteDensityVdb(const std::filesystem::path& path, const CountGrid& counts,
                             const GridFrame& frame, const DensityOptions& options,
                             const Metadata& metadata, const std::vector<Vec3Field>& fields) {
  std::optional<Result> result;
  try {
    result.emplace(counts, frame, options, metadata);
  } catch (const std::exception& e) {
    return absl::InternalError(
        absl::StrCat("building the grids of ", path.string(), ": ", e.what()));
  }
  std::vector<GridSource> grids = result->Sources(false);
  for (const Vec3Field& f : fields)
    grids.push_back({f.name, [&] { return FieldGrid(f, frame, options.conventions); }});
  return WriteResult(path, grids);
}

absl::Status WriteIntegerCountsVdb(const std::filesystem::path& path, const CountGrid& counts,
                                   const GridFrame& frame, const DensityOptions& options,
                                   const Metadata& metadata) {
  const DensityOptions o = IntegerCountsOptions(options);
  std::optional<Result> result;
  try {
    result.emplace(counts, frame, o, metadata);
  } catch (const std::exception& e) {
    return absl::InternalError(
        absl::StrCat("building the counts grid of ", path.string(), ": ", e.what()));
  }
  return WriteResult(path, result->Sources(true));
}

}  // namespace nimbus::vdb_native
