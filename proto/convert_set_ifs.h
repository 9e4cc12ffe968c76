// The validated form of a set_ifs spec (ALGORITHMS.md section 1) and the
// step that turns its set sources into voxel sets. ConvertSpec fills a
// SetIfsPlan; the set-IFS runner builds the sets and maps from it.
#pragma once

#include <cstdint>
#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "core/base/geometry.h"
#include "core/base/interrupter.h"
#include "core/io/mesh_io.h"
#include "core/chaos/point_map.h"
#include "core/sets/set_maps.h"
#include "core/sets/shapes.h"
#include "core/grid/voxel_set.h"
#include "nimbus/v1/spec.pb.h"
#include "proto/asset_paths.h"
#include "proto/spec_convert.h"

namespace nimbus::spec {

/// @brief A checked SetSource. Files are resolved and meshes already parsed,
/// so a bad mesh is refused at submit time, not halfway through a job.
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

/// @brief A checked SetMap.
struct SetMapPlan {
  SetMapKind kind = SetMapKind::kMedian;
  std::string field;
  /// Condensation set of median, rotated-median and constant maps.
  std::optional<SetSourcePlan> condensation;
  MedianOptions median;
  RotatedMedianOptions rotated;
  std::optional<PointMap> point;
};

/// @brief What a set-IFS job runs.
struct SetIfsPlan {
  std::vector<SetMapPlan> maps;
  /// Normalised, one per map.
  std::vector<double> probabilities;
  /// Book address letters, one per map.
  std::vector<std::string> labels;
  bool book = false;
  // Random iteration.
  uint64_t iterations = 0;
  uint64_t warmup = 16;
  // Book.
  int depth = 0;
  uint64_t pages = 0;
  uint64_t seed = 0;
  std::optional<SetSourcePlan> start;
  /// Memory the book may use for shared intermediate pages.
  uint64_t book_cache_bytes = uint64_t{256} << 20;
};

/// @brief Memoises built sets by SetSourcePlan::cache_key.
struct SetBuildCache {
  std::map<std::string, VoxelSet> sets;
};

/// Builds a source's voxel set on `frame`. Errors name the source's field
/// and file. `cache` may be null.
absl::StatusOr<VoxelSet> BuildSetSource(const SetSourcePlan& source, const GridFrame& frame,
                                        SetBuildCache* cache, Interrupter* interrupter = nullptr);

}  // namespace nimbus::spec
