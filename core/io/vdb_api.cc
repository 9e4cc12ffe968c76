// The parts of vdb_io.h that need no OpenVDB (sizes, estimates, frames),
// and the forwarders of the rest to the OpenVDB module (vdb_module.h).
#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <unordered_map>

#include "core/base/status_macros.h"
#include "core/io/vdb_io.h"
#include "core/io/vdb_module.h"

namespace nimbus {

namespace {

// Active voxels and leaves left by a box filter of factor f: the coarse
// voxels hit, and their 8^3 leaves (OpenVDB's, as the writers make them),
// each leaf a 512-bit mask.
GridSupport SupportAtFactor(const CountGrid& counts, int f) {
  GridSupport s;
  if (f == 1) {
    counts.ForEachLeaf([&](Int3, const uint32_t* v, const uint64_t*) {
      for (int i = 0; i < 512; ++i) s.voxels += v[i] != 0;
      ++s.leaves;
    });
    return s;
  }
  using Mask = std::array<uint64_t, 8>;
  std::unordered_map<uint64_t, Mask> leaves;
  uint64_t last_key = ~uint64_t{0};
  Mask* last = nullptr;  // voxels come tile by tile: mostly the same leaf again
  counts.ForEachVoxel([&](Int3 v, uint32_t) {
    const uint32_t x = uint32_t(v.x / f), y = uint32_t(v.y / f), z = uint32_t(v.z / f);
    const uint64_t key = (uint64_t(x >> 3) << 42) | (uint64_t(y >> 3) << 21) | (z >> 3);
    if (key != last_key) last = &leaves[key], last_key = key;
    const uint32_t bit = ((x & 7) << 6) | ((y & 7) << 3) | (z & 7);
    (*last)[bit >> 6] |= uint64_t{1} << (bit & 63);
  });
  for (const auto& [key, mask] : leaves)
    for (uint64_t word : mask) s.voxels += uint64_t(std::popcount(word));
  s.leaves = leaves.size();
  return s;
}

}  // namespace

const MetaValue* DenseVolume::Find(const std::string& key) const {
  for (const auto& [k, v] : metadata)
    if (k == key) return &v;
  return nullptr;
}

uint64_t OutputBytesPerVoxel(const DensityOptions& o) {
  uint64_t bytes = sizeof(float);
  if (o.color) bytes += 3 * sizeof(float);
  if (o.address_grid) bytes += sizeof(float);
  if (o.raw_counts == RawCounts::kFloat) bytes += sizeof(float);
  if (o.raw_counts == RawCounts::kInteger) bytes += sizeof(int64_t);
  return bytes;
}

uint64_t EstimatedFileBytes(GridSupport support, const DensityOptions& o) {
  const uint64_t f = o.conventions.half_float ? 2 : 4;
  uint64_t grids = 1, per_voxel = f;  // density
  if (o.color) grids += 1, per_voxel += 3 * f;
  if (o.address_grid) grids += 1, per_voxel += f;
  if (o.raw_counts != RawCounts::kNone) grids += 1, per_voxel += f;  // float counts
  return kFileOverheadBytes + support.voxels * per_voxel + support.leaves * grids * kLeafFileBytes;
}

int OutputDownsampleFactor(const CountGrid& counts, const DensityOptions& options) {
  const OutputConventions& c = options.conventions;
  if (!c.Downsamples()) return 1;
  auto fits = [&](GridSupport s) {
    return (c.max_voxels <= 0 || s.voxels <= uint64_t(c.max_voxels)) &&
           (c.target_file_bytes <= 0 ||
            EstimatedFileBytes(s, options) <= uint64_t(c.target_file_bytes));
  };
  const GridSupport fine = SupportAtFactor(counts, 1);
  if (fits(fine)) return 1;
  // A block holds at most f^3 voxels, so no factor below the cube root of
  // the excess can fit: start there instead of counting every factor.
  uint64_t limit = fine.voxels;
  if (c.max_voxels > 0) limit = std::min<uint64_t>(limit, uint64_t(c.max_voxels));
  if (c.target_file_bytes > 0) {
    // Voxel bytes alone, without leaves or overhead: still a lower bound.
    const uint64_t empty = EstimatedFileBytes({0, 0}, options);
    const uint64_t per_voxel = EstimatedFileBytes({1, 0}, options) - empty;
    const uint64_t room = uint64_t(c.target_file_bytes) > empty ? c.target_file_bytes - empty : 0;
    limit = std::min<uint64_t>(limit, room / per_voxel);
  }
  const Int3 r = counts.resolution();
  const int largest = std::max({r.x, r.y, r.z});
  int f = std::max(2, int(std::cbrt(double(fine.voxels) / double(std::max<uint64_t>(1, limit)))));
  for (; f < largest; ++f)
    if (fits(SupportAtFactor(counts, f))) return f;
  return std::max(1, largest);
}

double SuggestedDensity(uint64_t active_voxels, double mean_value, double voxel_size) {
  if (active_voxels == 0 || !(mean_value > 0) || !(voxel_size > 0)) return 1.0;
  const double crossed = std::cbrt(double(active_voxels));
  return std::clamp(kSuggestedDepth / (mean_value * voxel_size * crossed), 1.0, 1000.0);
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
    part->ForEachVoxel(
        [&](Int3 v, uint32_t n) { out.Add(v.x / factor, v.y / factor, v.z / factor, n); });
  }
  return out;
}

// ---- Forwarders to the module ----

absl::Status WriteDensityVdb(const std::filesystem::path& path, const CountGrid& counts,
                             const GridFrame& frame, const DensityOptions& options,
                             const Metadata& metadata) {
  return WriteDensityVdb(path, counts, frame, options, metadata, {});
}

absl::Status WriteDensityVdb(const std::filesystem::path& path, const CountGrid& counts,
                             const GridFrame& frame, const DensityOptions& options,
                             const Metadata& metadata, const std::vector<Vec3Field>& fields) {
  NIMBUS_ASSIGN_OR_RETURN(const VdbModule* vdb, LoadVdbModule());
  return vdb->write_density(path, counts, frame, options, metadata, fields);
}

absl::Status WriteIntegerCountsVdb(const std::filesystem::path& path, const CountGrid& counts,
                                   const GridFrame& frame, const DensityOptions& options,
                                   const Metadata& metadata) {
  NIMBUS_ASSIGN_OR_RETURN(const VdbModule* vdb, LoadVdbModule());
  return vdb->write_integer_counts(path, counts, frame, options, metadata);
}

absl::Status WriteFloatVolumeVdb(const std::filesystem::path& path, const FloatVolume& volume,
                                 const Metadata& metadata, const OutputConventions& conventions) {
  NIMBUS_ASSIGN_OR_RETURN(const VdbModule* vdb, LoadVdbModule());
  return vdb->write_float_volume(path, volume, metadata, conventions);
}

absl::StatusOr<std::vector<int64_t>> ReadIntegerCountsVdb(const std::filesystem::path& path,
                                                          Int3 resolution) {
  NIMBUS_ASSIGN_OR_RETURN(const VdbModule* vdb, LoadVdbModule());
  return vdb->read_integer_counts(path, resolution);
}

absl::StatusOr<std::string> DensityVdbBytes(const CountGrid& counts, const GridFrame& frame,
                                            const DensityOptions& options,
                                            const Metadata& metadata) {
  NIMBUS_ASSIGN_OR_RETURN(const VdbModule* vdb, LoadVdbModule());
  return vdb->density_bytes(counts, frame, options, metadata);
}

absl::StatusOr<DenseVolume> ReadVdbFile(const std::filesystem::path& path,
                                        const std::string& name) {
  NIMBUS_ASSIGN_OR_RETURN(const VdbModule* vdb, LoadVdbModule());
  return vdb->read_file(path, name);
}

absl::StatusOr<DenseVolume> ReadVdbBytes(const std::string& bytes, const std::string& name) {
  NIMBUS_ASSIGN_OR_RETURN(const VdbModule* vdb, LoadVdbModule());
  return vdb->read_bytes(bytes, name);
}

absl::StatusOr<DenseVec3Volume> ReadVec3VdbFile(const std::filesystem::path& path,
                                                const std::string& name) {
  NIMBUS_ASSIGN_OR_RETURN(const VdbModule* vdb, LoadVdbModule());
  return vdb->read_vec3_file(path, name);
}

absl::Status CheckUntrustedVdb(const std::filesystem::path& path,
                               const std::filesystem::path& laundered) {
  NIMBUS_ASSIGN_OR_RETURN(const VdbModule* vdb, LoadVdbModule());
  return vdb->check_untrusted(path, laundered);
}

}  // namespace nimbus
