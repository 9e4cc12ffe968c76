// Exact Euclidean feature (closest-point) transform of a voxel set: the
// nearest-point queries behind the median morph (docs/algorithms.md#the-median-morph).
#pragma once

#include <cstdint>
#include <optional>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/base/big_buffer.h"
#include "core/base/geometry.h"
#include "core/base/interrupter.h"
#include "core/grid/voxel_set.h"

namespace nimbus {

/// A voxel index packed as x | y << 10 | z << 20 (VoxelSet::kMaxResolution
/// is 1024, so 10 bits per axis suffice).
using PackedVoxel = uint32_t;
inline constexpr PackedVoxel kNoVoxel = 0xffffffffu;

constexpr PackedVoxel PackVoxel(int x, int y, int z) {
  return uint32_t(x) | (uint32_t(y) << 10) | (uint32_t(z) << 20);
}
constexpr PackedVoxel PackVoxel(Int3 v) { return PackVoxel(v.x, v.y, v.z); }
constexpr Int3 UnpackVoxel(PackedVoxel p) {
  return {int(p & 1023u), int((p >> 10) & 1023u), int(p >> 20)};
}

/// Squared world-space distance between the centres of two voxels whose
/// sides are `h` (anisotropic voxels weigh each axis by its size).
inline double SquaredDistance(Int3 a, Int3 b, Vec3 h) {
  const double dx = (a.x - b.x) * h.x, dy = (a.y - b.y) * h.y, dz = (a.z - b.z) * h.z;
  return dx * dx + dy * dy + dz * dz;
}

/// @brief For each voxel of `box`, the nearest member of a set (packed), or
/// kNoVoxel when the set is empty.
struct FeatureField {
  VoxelBox box;
  // x fastest, then y, then z, over `box`. The transform writes every entry
  // it reads, so the buffer skips the zero fill (core/base/big_buffer.h);
  // with queries, entries no query needs may be left as they were.
  std::vector<PackedVoxel, BigBufferAllocator<PackedVoxel>> nearest;

  size_t Index(int x, int y, int z) const {
    const Int3 s = box.Size();
    return size_t(x - box.min.x) +
           size_t(s.x) * (size_t(y - box.min.y) + size_t(s.y) * size_t(z - box.min.z));
  }
  PackedVoxel At(int x, int y, int z) const { return nearest[Index(x, y, z)]; }
  PackedVoxel At(Int3 v) const { return At(v.x, v.y, v.z); }
};

struct FeatureTransformOptions {
  /// Region to compute; the whole lattice when unset. The field is computed
  /// on the hull of this box and the set's bounding box, which keeps it exact.
  std::optional<VoxelBox> box;
  /// When set, results are only guaranteed at these voxels: lines of the
  /// last two passes that hold no query are skipped, and with exact
  /// arithmetic so are sites out of reach of queries near the set
  /// (docs/condensation.md#feature-transform).
  const VoxelSet* queries = nullptr;
  /// The set's bounding box, when the caller already knows it (the set is
  /// then non-empty): saves a serial scan of the whole lattice. It must be
  /// exact, as VoxelSet::BoundingBox would give it.
  std::optional<VoxelBox> set_box;
};

/// @brief Exact Euclidean feature transform in linear time (Maurer-style
/// separable algorithm): per axis, a 1D nearest-site pass along x, then
/// lower envelopes of parabolas along y and z. Ties resolve the same way on
/// every run and thread count (lines are independent), so results are
/// deterministic. Members map to themselves. Lines run in parallel (TBB).
///
/// `out`'s buffer is reused between calls. Returns CancelledError when
/// interrupted (the field is then incomplete).
absl::Status ComputeFeatureTransform(const VoxelSet& set, Vec3 voxel_size,
                                     const FeatureTransformOptions& options, FeatureField& out,
                                     Interrupter* interrupter = nullptr);

/// Whole-lattice convenience form.
absl::StatusOr<FeatureField> ComputeFeatureTransform(const VoxelSet& set, Vec3 voxel_size,
                                                     Interrupter* interrupter = nullptr);

/// Largest distance (world units) from a member of `a` to the set `b`:
/// the directed Hausdorff distance. Infinity when `b` is empty and `a` not.
absl::StatusOr<double> DirectedHausdorff(const VoxelSet& a, const VoxelSet& b, Vec3 voxel_size,
                                         Interrupter* interrupter = nullptr);

/// Symmetric Hausdorff distance between two voxel sets, in world units.
absl::StatusOr<double> HausdorffDistance(const VoxelSet& a, const VoxelSet& b, Vec3 voxel_size,
                                         Interrupter* interrupter = nullptr);

}  // namespace nimbus
