// Conversion of visit counts to OpenVDB fog volumes, and VDB file/byte I/O.
// OpenVDB stays behind this header (pimpl-free: only core types cross it),
// in the libnimbus_vdb.so module that these functions load on first use
// (vdb_module.h): a missing module is a FAILED_PRECONDITION status.
#pragma once

#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>
#include <utility>
#include <variant>
#include <vector>

#include "absl/status/statusor.h"
#include "core/grid/count_grid.h"
#include "core/base/geometry.h"
#include "core/grid/palette.h"

namespace nimbus {

/// How visit counts become density values before normalisation to [0, 1].
enum class DensityMapping {
  kLinear,  // c / max
  kSqrt,    // sqrt(c / max)
  kLog,     // log(1 + c) / log(1 + max), flame-style
  kGamma,   // (c / max)^(1 / gamma)
};

/// Unnormalised visit counts written next to the density, for compositing
/// shards (sum the count grids, then map).
enum class RawCounts {
  kNone,
  kFloat,    // FloatGrid "counts" (exact up to 2^24 per voxel)
  // The same float grid in the result, plus the exact counts as an
  // Int64Grid "counts" in a file of its own (WriteIntegerCountsVdb): Debian's
  // pyopenvdb and Blender cannot open a file that holds an Int64 grid.
  kInteger,
};

/// The world's up axis of a written file. Nimbus computes in the spec's
/// frame, Y up; kZ rotates world space by (x, y, z) -> (x, -z, y) in every
/// grid's transform, so the voxels are the same and +Y lands on +Z.
enum class UpAxis { kY, kZ };

/// @brief File conventions every writer applies (docs/dcc.md): up axis,
/// half floats and automatic downsampling.
struct OutputConventions {
  UpAxis up_axis = UpAxis::kY;
  /// Save float and Vec3f grids as 16-bit halves.
  bool half_float = false;
  /// Most active voxels per grid (0: no limit).
  int64_t max_voxels = 0;
  /// Largest estimated file size, EstimatedFileBytes (0: no limit).
  int64_t target_file_bytes = 0;
  bool Downsamples() const { return max_voxels > 0 || target_file_bytes > 0; }
};

struct DensityOptions {
  DensityMapping mapping = DensityMapping::kLinear;
  double gamma = 2.2;
  std::string grid_name = "density";
  /// Write a Vec3f grid "Cd" = palette(mean colour coordinate) for counts
  /// that carry colour sums.
  bool color = false;
  Palette palette;
  /// Write a float grid "address" with the mean colour coordinate in [0, 1].
  bool address_grid = false;
  RawCounts raw_counts = RawCounts::kNone;
  OutputConventions conventions;
  /// When set, every written density is multiplied by max(0,
  /// modulation(voxel centre in world space)): a fractal field's detail on
  /// any job's result (JobSpec.detail). Unset: densities as counted.
  std::function<double(const Vec3&)> modulation;
};

/// Bytes per active voxel the output grids of `options` take in memory.
uint64_t OutputBytesPerVoxel(const DensityOptions& options);

/// What a grid's file size depends on: its active voxels and its 8^3 leaves.
struct GridSupport {
  uint64_t voxels = 0;
  uint64_t leaves = 0;
};

/// Estimated bytes of a result file whose grids have `support`: per grid,
/// the stored bytes of its active voxels (4 per float component, 2 with
/// half_float) plus kLeafFileBytes per leaf (masks and block headers), plus
/// kFileOverheadBytes (header, transforms, metadata). Blosc is not counted,
/// so real files come out at or below it.
uint64_t EstimatedFileBytes(GridSupport support, const DensityOptions& options);
inline constexpr uint64_t kLeafFileBytes = 200;
inline constexpr uint64_t kFileOverheadBytes = 4096;

/// @brief The downsampling factor the writers use for `counts`: 1 unless
/// options.conventions limits voxels or file size, else the smallest
/// integer factor f whose f^3 box filter leaves at most max_voxels active
/// voxels and an estimated file of at most target_file_bytes (at worst a
/// factor that leaves one voxel). Depends on the counts' support only.
int OutputDownsampleFactor(const CountGrid& counts, const DensityOptions& options);

/// The suggested shader density multiplier (metadata
/// nimbus_suggested_density, docs/dcc.md): optical depth kSuggestedDepth
/// along a ray that crosses cbrt(active) voxels of the mean active value,
/// tau / (mean * voxel_size * cbrt(active)), clamped to [1, 1000]; 1 for an
/// empty grid. `voxel_size` is the geometric mean edge in world units.
double SuggestedDensity(uint64_t active_voxels, double mean_value, double voxel_size);
inline constexpr double kSuggestedDepth = 2.0;

using MetaValue = std::variant<std::string, int64_t, double>;
using Metadata = std::vector<std::pair<std::string, MetaValue>>;

/// @brief A sparse Vec3f grid written beside the density (e.g. the
/// velocity "v" of jelly frames), on voxels of its own.
struct Vec3Field {
  std::string name;
  std::vector<std::pair<Int3, Vec3>> voxels;
};

/// Writes `counts` as a FloatGrid (fog volume, max value 1) whose transform
/// maps voxels onto `frame.bounds`, Blosc-compressed, through a temporary
/// file renamed into place so readers never see a partial file. The grid
/// also records nimbus_resolution / nimbus_bounds_min / nimbus_bounds_max and
/// the normalisation (nimbus_max_count, nimbus_total_count,
/// nimbus_density_mapping, nimbus_density_gamma). Optional grids: "Cd",
/// "address" and "counts" (see DensityOptions), on the same voxels.
///
/// options.conventions apply to every grid: a downsampling factor f > 1
/// (OutputDownsampleFactor) box-filters each grid over f^3 blocks (density
/// averaged, so density times voxel volume keeps its sum; counts summed;
/// Cd and address density-weighted means) and the frame metadata names the
/// coarse lattice (DownsampleFrame); nimbus_downsample_factor records f.
/// nimbus_up_axis ("Y"/"Z") names the transform's up axis; the frame
/// metadata stays in the spec's Y-up frame. nimbus_suggested_density is
/// SuggestedDensity of the written density grid.
absl::Status WriteDensityVdb(const std::filesystem::path& path, const CountGrid& counts,
                             const GridFrame& frame, const DensityOptions& options,
                             const Metadata& metadata);
/// The same plus one Vec3f grid per field (vector type "contravariant
/// relative", as velocities are), carrying the frame metadata.
absl::Status WriteDensityVdb(const std::filesystem::path& path, const CountGrid& counts,
                             const GridFrame& frame, const DensityOptions& options,
                             const Metadata& metadata, const std::vector<Vec3Field>& fields);

/// Writes the exact visit counts as an Int64Grid "counts" (same transform,
/// frame and normalisation metadata as the density) to its own file, through
/// a temporary file renamed into place: the side file of RawCounts::kInteger.
/// The result's `options` give the conventions, so both files share the
/// downsampling factor and transform.
absl::Status WriteIntegerCountsVdb(const std::filesystem::path& path, const CountGrid& counts,
                                   const GridFrame& frame, const DensityOptions& options,
                                   const Metadata& metadata);

/// @brief A dense float volume over a frame (x slowest, z fastest), for
/// engines that compute values rather than count visits (fractal fields).
struct FloatVolume {
  GridFrame frame;
  std::string grid_name = "density";
  /// Fog volume: zeros are inactive. Level set: values with |v| < background
  /// are active, the rest become ±background by sign (signed flood fill).
  bool level_set = false;
  float background = 0;
  std::vector<float> values;
};

/// Writes `volume` as one FloatGrid (Blosc, renamed into place, content
/// UUID) with the frame metadata and `metadata`, in the up axis and
/// precision of `conventions` (their downsampling does not apply here).
absl::Status WriteFloatVolumeVdb(const std::filesystem::path& path, const FloatVolume& volume,
                                 const Metadata& metadata,
                                 const OutputConventions& conventions = {});

/// Reads the exact counts of such a file densely (x slowest, z fastest).
absl::StatusOr<std::vector<int64_t>> ReadIntegerCountsVdb(const std::filesystem::path& path,
                                                          Int3 resolution);

/// Same grid as WriteDensityVdb, serialised to bytes (a VDB stream).
absl::StatusOr<std::string> DensityVdbBytes(const CountGrid& counts, const GridFrame& frame,
                                            const DensityOptions& options,
                                            const Metadata& metadata);

/// @brief A float grid read back into a dense array, x slowest, z fastest.
struct DenseVolume {
  std::string name;
  GridFrame frame;
  std::string grid_class;  // "fog volume", ...
  std::vector<float> values;
  Metadata metadata;
  /// World-space position of voxel (0,0,0)'s centre and voxel size, from the
  /// grid's transform (independent of the metadata).
  Vec3 origin_center;
  Vec3 voxel_size;
  /// The grid's whole index-to-world map (rotated for UpAxis::kZ).
  Affine3 index_to_world;

  float At(int x, int y, int z) const {
    return values[(size_t(x) * frame.resolution.y + y) * frame.resolution.z + z];
  }
  const MetaValue* Find(const std::string& key) const;
};

/// @brief A Vec3f grid read back densely (x slowest, z fastest).
struct DenseVec3Volume {
  Int3 resolution;
  std::vector<Vec3> values;
  std::vector<bool> active;
  const Vec3& At(int x, int y, int z) const {
    return values[(size_t(x) * resolution.y + y) * resolution.z + z];
  }
};
/// Reads Vec3f grid `name` (e.g. "Cd"), using the density grid's frame.
absl::StatusOr<DenseVec3Volume> ReadVec3VdbFile(const std::filesystem::path& path,
                                                const std::string& name = "Cd");

/// Reads grid `name` of a Nimbus VDB file (or stream bytes) into a DenseVolume.
absl::StatusOr<DenseVolume> ReadVdbFile(const std::filesystem::path& path,
                                        const std::string& name = "density");
absl::StatusOr<DenseVolume> ReadVdbBytes(const std::string& bytes,
                                         const std::string& name = "density");

/// @brief Reads every grid of an untrusted file whole (no delayed loading)
/// and walks every tree, so that a damaged file fails here; with
/// `laundered` not empty, then writes its float grids there with OpenVDB's
/// writer (through a temporary file renamed into place). Meant for a
/// sandboxed child process (server/untrusted_file.h): INVALID_ARGUMENT
/// whose message is the reason a file is refused.
absl::Status CheckUntrustedVdb(const std::filesystem::path& path,
                               const std::filesystem::path& laundered);

/// Sums `parts` into a grid coarser by `factor` per axis, for previews.
CountGrid DownsampleCounts(const std::vector<const CountGrid*>& parts, int factor);
/// The coarse frame matching DownsampleCounts(…, factor).
GridFrame DownsampleFrame(const GridFrame& frame, int factor);
/// The smallest factor that brings every axis to at most `max_resolution`.
int DownsampleFactor(Int3 resolution, int max_resolution);

}  // namespace nimbus
