// Maps on voxel sets for IFS with condensation (docs/algorithms.md#ifs-with-condensation-on-voxel-sets):
// the median morph toward a condensation set, its rotated variant,
// Barnsley's constant condensation and point maps lifted to sets. They
// share one interface so a set IFS can mix them freely.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/sets/feature_transform.h"
#include "core/base/geometry.h"
#include "core/base/interrupter.h"
#include "core/chaos/point_map.h"
#include "core/grid/voxel_set.h"

namespace nimbus {

/// Options of the (left) median D_A(B) and the median M(A, B).
struct MedianOptions {
  /// Gap filling. Face-adjacent voxels of A whose nearest points in B are
  /// at most this many voxels apart (per axis), in directions within 60
  /// degrees, lie where the nearest-point map is continuous, so the exact
  /// image is solid there: when their images are two or more voxels apart,
  /// the segment between them and the image of the voxel cube they span are
  /// filled. Other pairs straddle B's medial axis, where the exact median
  /// tears too, and stay open. 0 disables filling.
  int bridge_max_jump = 4;
  /// Picks the side of midpoints that fall on a voxel face (see LeftMedian).
  /// Set maps combine it with SetMapWorkspace::seed (xor), so each
  /// application of a map rounds afresh.
  uint64_t seed = 0;
};

/// @brief D_A(B): every voxel a of A moved halfway to its nearest voxel b of
/// B (voxels of A inside B stay), plus gap filling (MedianOptions). A
/// midpoint on a voxel face goes up or down along each axis as the seed
/// says, the same for every voxel of one call: symmetric in a and b,
/// monotone, and unbiased over seeds. Deterministic for a seed.
absl::StatusOr<VoxelSet> LeftMedian(const VoxelSet& a, const VoxelSet& b, const GridFrame& frame,
                                    const MedianOptions& options = {},
                                    Interrupter* interrupter = nullptr);

/// @brief The median morph M(A, B) = D_A(B) ∪ D_B(A). Symmetric, and
/// M(C, C) = C. Both sets must be non-empty.
absl::StatusOr<VoxelSet> Median(const VoxelSet& a, const VoxelSet& b, const GridFrame& frame,
                                const MedianOptions& options = {},
                                Interrupter* interrupter = nullptr);

/// Options of the rotated median M~.
struct RotatedMedianOptions {
  MedianOptions median;
  /// Angle factor: degrees of rotation per world unit of distance between
  /// the bounding-box centres of the two sets.
  double degrees_per_unit = 90.0;
  /// Rotation axis (world space, need not be unit length).
  Vec3 axis{0, 0, 1};
  /// Superpose the sets' bounding boxes midway before taking the median
  /// (the reference description's construction; docs/algorithms.md#the-rotated-median). When false the plain median is rotated.
  bool superpose = true;
};

/// @brief The rotated median M~(A, B): the bounding boxes of A and B are
/// superposed midway between their centres (whole-voxel shifts), the median
/// is taken there, and the result is rotated about that midpoint by
/// degrees_per_unit x |centre(A) - centre(B)| around `axis`. The angle
/// vanishes as the sets meet, so M~(C, C) = C and f(I) = M~(I, C) still
/// condenses onto C; the angle factor changes the path continuously.
absl::StatusOr<VoxelSet> RotatedMedian(const VoxelSet& a, const VoxelSet& b, const GridFrame& frame,
                                       const RotatedMedianOptions& options = {},
                                       Interrupter* interrupter = nullptr);

/// @brief Image of a set under a world-space affine map without holes:
/// every output voxel whose centre pulls back into a member is set, and
/// when the map shrinks some direction the members' centres are also pushed
/// forward so thin parts survive. Voxels mapped outside the lattice are lost.
VoxelSet TransformSet(const VoxelSet& set, const GridFrame& frame, const Affine3& world_map);

/// Timing gathered by the maps, for benchmarks and progress reports.
struct SetMapStats {
  uint64_t applications = 0;
  double seconds = 0;          // total time inside Apply
  double nearest_seconds = 0;  // building per-step feature transforms
};

/// Per-moving-voxel scratch of one half of a median, indexed by the voxels'
/// rank in row order (entries are written before they are read).
struct MovingBuffers {
  std::vector<PackedVoxel, BigBufferAllocator<PackedVoxel>> images, nearest;
  std::vector<uint32_t> rank_first;  // rank of each row word's first moving voxel
};

/// @brief Scratch buffers and per-call parameters for SetMap::Apply. One
/// workspace per concurrent caller; buffers are reused between calls.
struct SetMapWorkspace {
  Interrupter* interrupter = nullptr;
  /// Seed for maps that draw random numbers (nonlinear point maps); callers
  /// set it per application to keep runs reproducible.
  uint64_t seed = 0;
  SetMapStats stats;

  // Internal buffers.
  VoxelSet moving_a, moving_b, shifted, staged;
  FeatureField field;
  MovingBuffers side_a, side_b;  // one per half of a median (they may overlap)
};

enum class SetMapKind { kMedian, kRotatedMedian, kConstant, kPoint };

/// @brief A map on voxel sets over a fixed GridFrame.
class SetMap {
 public:
  virtual ~SetMap() = default;
  virtual SetMapKind kind() const = 0;
  /// Short human-readable description.
  virtual std::string Describe() const = 0;
  /// Computes `out` = f(`in`). Both have the frame's resolution; `out` is
  /// overwritten and must not alias `in`.
  virtual absl::Status Apply(const VoxelSet& in, VoxelSet& out, SetMapWorkspace& ws) const = 0;

  const GridFrame& frame() const { return frame_; }

 protected:
  explicit SetMap(const GridFrame& frame) : frame_(frame) {}

 private:
  GridFrame frame_;
};

using SetMapPtr = std::shared_ptr<const SetMap>;

/// @brief f_C(I) = M(I, C). C's feature transform is computed here, once
/// (4 bytes per lattice voxel); each Apply computes I's transform only over
/// the box that C \ I needs and reads C's for I \ C. f_C(empty) = C.
absl::StatusOr<SetMapPtr> MakeMedianMap(const GridFrame& frame, VoxelSet condensation,
                                        const MedianOptions& options = {},
                                        Interrupter* interrupter = nullptr);

/// @brief f_C(I) = M~(I, C) (see RotatedMedian), C's transform precomputed.
absl::StatusOr<SetMapPtr> MakeRotatedMedianMap(const GridFrame& frame, VoxelSet condensation,
                                               const RotatedMedianOptions& options = {},
                                               Interrupter* interrupter = nullptr);

/// @brief Barnsley's constant condensation f_0(I) = C.
absl::StatusOr<SetMapPtr> MakeConstantMap(const GridFrame& frame, VoxelSet condensation);

struct PointSetMapOptions {
  /// Nonlinear maps: each voxel is sampled n^3 times, n = ceil(2 x local
  /// stretch in output voxels), clamped to [1, max_subdivision].
  int max_subdivision = 4;
};

/// @brief A point map (affine or nonlinear, world space) applied to every
/// voxel of a set. Affine maps use TransformSet. Nonlinear maps push voxel
/// centres forward, subdividing voxels where the map stretches so images
/// stay hole-free; their random numbers come from SetMapWorkspace::seed.
absl::StatusOr<SetMapPtr> MakePointSetMap(const GridFrame& frame, PointMap map,
                                          const PointSetMapOptions& options = {});

}  // namespace nimbus
