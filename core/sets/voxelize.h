// Mesh voxelisation into interior VoxelSets on a job's GridFrame: the step
// that turns an artist's sketch mesh into a condensation set
// (docs/algorithms.md#maps-that-act-on-sets). OpenVDB stays inside voxelize.cc.
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>

#include "absl/status/statusor.h"
#include "core/base/geometry.h"
#include "core/base/interrupter.h"
#include "core/io/mesh_io.h"
#include "core/grid/voxel_set.h"

namespace nimbus {

/// @brief Edge statistics of a mesh after welding vertices that share exact
/// coordinates (OBJ/STL files often duplicate them along seams).
struct MeshTopology {
  int64_t welded_vertices = 0;
  int64_t edges = 0;
  int64_t boundary_edges = 0;        // used by one triangle: a hole's rim
  int64_t nonmanifold_edges = 0;     // used by three or more triangles
  int64_t inconsistent_edges = 0;    // two triangles traverse it the same way
  int64_t degenerate_triangles = 0;  // repeated corner after welding

  /// Closed surface: every edge has exactly two triangles.
  bool watertight() const { return boundary_edges == 0 && nonmanifold_edges == 0; }
};

/// Counts boundary, non-manifold and inconsistently oriented edges.
MeshTopology AnalyzeTopology(const TriangleMesh& mesh);

/// How the inside of the mesh is decided.
enum class InteriorMethod {
  /// Level set for watertight meshes, ray vote otherwise.
  kAuto,
  /// OpenVDB meshToVolume signed distance: exact sign for closed surfaces.
  kLevelSet,
  /// Winding numbers along rays in the six axis directions, inside when at
  /// least four agree; optionally plus a surface shell from OpenVDB's
  /// unsigned distance field. Tolerates holes and open seams.
  kRayVote,
};

struct VoxelizeOptions {
  /// Scale (uniformly) and centre the mesh into the frame's bounds.
  bool fit = false;
  /// With `fit`: voxels left free between the mesh's box and the bounds on
  /// each side (along the tightest axis).
  double fit_margin_voxels = 2.0;
  InteriorMethod method = InteriorMethod::kAuto;
  /// Ray vote: voxels whose centre lies within this many voxels of the
  /// surface are added too (OpenVDB unsigned distance), which keeps thin
  /// parts. When the vote finds no volume at all (an open sheet), a shell
  /// of at least half a voxel is used so the sketch still leaves a trace.
  double shell_voxels = 0.0;
};

/// @brief The voxelised sketch: voxels whose centres lie inside the mesh.
struct VoxelizeResult {
  VoxelSet interior;
  MeshTopology topology;
  bool watertight = false;
  InteriorMethod method = InteriorMethod::kAuto;  // the method actually used
  /// Mesh-to-world map that was applied (identity unless fitting).
  Affine3 placement;
};

/// World map that scales `mesh` uniformly (aspect preserved) and centres it
/// in `frame`'s bounds, leaving `margin_voxels` on the tightest axis.
/// Flat axes (zero extent) are ignored when choosing the scale.
Affine3 FitPlacement(const Bounds& mesh, const GridFrame& frame, double margin_voxels);

/// @brief Voxelises a mesh on `frame` (anisotropic voxels allowed). A voxel
/// is inside when its centre is. Watertight meshes go through OpenVDB's
/// meshToVolume; meshes with holes or non-manifold edges through the ray
/// vote (see InteriorMethod), and are reported as not watertight.
absl::StatusOr<VoxelizeResult> VoxelizeMesh(const TriangleMesh& mesh, const GridFrame& frame,
                                            const VoxelizeOptions& options = {},
                                            Interrupter* interrupter = nullptr);

/// LoadMesh followed by VoxelizeMesh: a sketch file as a condensation set.
absl::StatusOr<VoxelizeResult> LoadAndVoxelize(const std::filesystem::path& path,
                                               const GridFrame& frame,
                                               const VoxelizeOptions& options = {},
                                               Interrupter* interrupter = nullptr);

/// Writes a watertight mesh's signed distance on `frame` (narrow band of 3
/// voxels, grid class "level set", name `grid_name`) as a .vdb file: how a
/// sketch becomes a grid asset, and the round trip LoadGridSet reads back.
absl::Status SaveMeshLevelSet(const TriangleMesh& mesh, const GridFrame& frame,
                              const std::filesystem::path& path,
                              const std::string& grid_name = "surface");

struct GridSetOptions {
  /// Grid to read; empty: the first float grid of the file.
  std::string grid_name;
  /// Fog volumes: voxels whose density exceeds this are inside.
  double threshold = 0.5;
};

/// @brief A .vdb file's float grid as a set on `frame`: each voxel centre
/// is looked up in world space (nearest grid voxel). Level sets (grid class
/// "level set") are inside where the value is negative, other grids where
/// it exceeds the threshold. Errors name the file; an empty result is
/// INVALID_ARGUMENT (the grid misses the frame).
absl::StatusOr<VoxelSet> LoadGridSet(const std::filesystem::path& path, const GridFrame& frame,
                                     const GridSetOptions& options = {},
                                     Interrupter* interrupter = nullptr);

}  // namespace nimbus
