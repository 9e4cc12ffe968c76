// @brief Set sources: the voxel sets a set IFS starts from or condenses
// onto (sketch meshes, VDB grids, shapes), checked once and built on a grid
// when a job runs (docs/condensation.md).
//
//   SetBuildCache cache;
//   NIMBUS_ASSIGN_OR_RETURN(VoxelSet set, BuildSetSource(plan, frame, &cache, intr));
#pragma once

#include <filesystem>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "core/base/geometry.h"
#include "core/base/interrupter.h"
#include "core/grid/voxel_set.h"
#include "core/io/mesh_io.h"
#include "core/sets/shapes.h"

namespace nimbus {

/// @brief A checked set source: a mesh or grid file, a shape, or a union
/// of sources. Files are resolved and meshes already parsed by the spec
/// converter, so a bad mesh is refused at submit time, not halfway through a
/// job.
struct SetSourcePlan {
  enum class Kind { kMesh, kGrid, kSphere, kBox, kTorus, kRandomBalls, kUnion };
  Kind kind = Kind::kSphere;
  /// Field path of the source, for messages ("set_ifs.maps[0].condensation").
  std::string field;
  /// Deterministic serialisation of the source message: equal keys give
  /// equal sets, so a sketch used twice is voxelised once.
  std::string cache_key;

  // kMesh and kGrid.
  std::filesystem::path file;  // resolved local file
  std::string file_label;      // how the spec named it (path or sha256)
  std::string file_format;     // ".obj", ".ply", ... when known; else from the name
  std::shared_ptr<const TriangleMesh> mesh;
  bool fit = true;
  double fit_margin_voxels = 2.0;
  Affine3 transform;  // after fitting
  double shell_voxels = 0.0;
  std::string grid_name;
  double threshold = 0.5;

  // Shapes (world units).
  Vec3 center;
  double radius = 0;
  Bounds box;
  Vec3 axis{0, 0, 1};
  double major_radius = 0, minor_radius = 0;
  RandomBallsOptions balls;

  /// Union parts; for kRandomBalls, parts[0] is the region.
  std::vector<SetSourcePlan> parts;
};

/// @brief Memoises built sets by SetSourcePlan::cache_key.
struct SetBuildCache {
  std::map<std::string, VoxelSet> sets;
};

/// Builds a source's voxel set on `frame`. Errors name the source's field
/// and file. `cache` may be null.
absl::StatusOr<VoxelSet> BuildSetSource(const SetSourcePlan& source, const GridFrame& frame,
                                        SetBuildCache* cache, Interrupter* interrupter = nullptr);

}  // namespace nimbus
