// Per-component accumulation and the `component` label grid written next to
// the density of an IFS-matrix job (docs/ifs_matrices.md). OpenVDB stays in
// the .cc.
#pragma once

#include <cstdint>
#include <filesystem>
#include <vector>

#include "absl/status/statusor.h"
#include "core/grid/count_grid.h"
#include "core/base/geometry.h"
#include "core/io/vdb_io.h"

namespace nimbus {

enum class ComponentGridType {
  kNone,   // density only
  kInt,    // float "component" in the result, plus an Int32 "component" in a side file
  kFloat,  // FloatGrid "component"
};

/// @brief Sums per-component visit counts into one density and keeps, per
/// voxel, the label of the component with the most visits. Ties keep the
/// earlier label, so adding labels in increasing order gives ties to the
/// lower label.
class ComponentAccumulator {
 public:
  explicit ComponentAccumulator(Int3 resolution);

  /// Adds one component's counts under `label` (>= 0).
  void Add(int32_t label, const CountGrid& counts);

  /// Sum of every component's counts.
  const CountGrid& density() const { return density_; }
  /// Label at a voxel, -1 where no component put a point.
  int32_t LabelAt(int x, int y, int z) const;
  /// Voxels per label (index = label), for stats and tests.
  std::vector<uint64_t> VoxelsPerLabel() const;
  /// Calls f(x, y, z, label) for every labelled voxel, in tile order.
  template <typename F>
  void ForEachLabel(F&& f) const {
    label_plus_one_.ForEachVoxel(
        [&](Int3 v, uint32_t label) { f(v.x, v.y, v.z, int32_t(label) - 1); });
  }

  /// Worst-case bytes of the three grids kept here.
  static uint64_t MaxMemoryBytes(Int3 resolution);

 private:
  CountGrid density_;
  CountGrid best_;            // largest per-component count so far
  CountGrid label_plus_one_;  // 0 = no label
};

/// @brief Writes the density grid exactly as WriteDensityVdb does, plus a
/// float `component` grid (background -1, only labelled voxels active, same
/// transform and nimbus_* frame metadata), to one VDB file through a
/// temporary file renamed into place.
///
/// The result file never holds an Int32 grid, whatever `type`: Debian's
/// pyopenvdb (and other builds that wrap only float, bool and Vec3f grids)
/// refuse a whole file, even its metadata, when one grid has another type.
/// Labels are small integers, exact as floats. For kInt the labels are also
/// written as an Int32 `component` grid, alone, to `int32_path` when that
/// is not empty; the float grid's `nimbus_component_int32_file` metadata
/// then names that file.
absl::Status WriteDensityAndComponentVdb(const std::filesystem::path& path,
                                         const ComponentAccumulator& acc, const GridFrame& frame,
                                         const DensityOptions& options, ComponentGridType type,
                                         const Metadata& metadata,
                                         const std::filesystem::path& int32_path = {});

/// Reads the `component` grid (float or Int32) of a result file or of an
/// Int32 side file into a dense array, x slowest, z fastest, -1 where
/// inactive.
absl::StatusOr<std::vector<int32_t>> ReadComponentGrid(const std::filesystem::path& path,
                                                       Int3 resolution);

}  // namespace nimbus
