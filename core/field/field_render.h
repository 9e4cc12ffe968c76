// @brief Turns a fractal field into results: density volumes (optionally
// shaped by a signed distance), height fields, terrain level sets and
// 16-bit height maps.
#pragma once

#include <vector>

#include "absl/status/statusor.h"
#include "core/base/geometry.h"
#include "core/base/interrupter.h"
#include "core/field/field_grid.h"
#include "core/field/field_plan.h"
#include "core/io/png_io.h"
#include "core/io/vdb_io.h"

namespace nimbus {

/// The voxel centres of `frame`'s first `space_dims` axes at time t.
FieldGrid VoxelCentres(const GridFrame& frame, int space_dims, double t);

/// Density of every voxel of `frame` (x slowest, z fastest); `shape_sdf`
/// (same layout, world units) when the plan has a shape.
absl::StatusOr<FloatVolume> RenderDensity(const FractalField& field, const FractalFieldPlan& plan,
                                          const GridFrame& frame, double t,
                                          const std::vector<float>* shape_sdf,
                                          Interrupter* interrupter = nullptr);

/// @brief Heights (world z) over the frame's x-y voxel columns, x slowest.
struct HeightField {
  int nx = 0, ny = 0;
  std::vector<float> heights;
  std::vector<float> normalized;  // v in [-1, 1]
};
absl::StatusOr<HeightField> RenderHeights(const FractalField& field, const FractalFieldPlan& plan,
                                          const GridFrame& frame, double t,
                                          Interrupter* interrupter = nullptr);

/// The terrain as a level set on `frame`: (z - h) / sqrt(1 + |grad h|^2),
/// negative below the ground, narrow band of 3 voxels.
FloatVolume TerrainLevelSet(const HeightField& h, const GridFrame& frame);

/// 16-bit height map: (v + 1) / 2 * 65535, north (max y) on the top row.
Gray16Image HeightMap16(const HeightField& h);

/// Signed distance (world units, negative inside) to a set source built on
/// `frame`, from exact feature transforms of the set and its complement.
absl::StatusOr<std::vector<float>> ShapeSignedDistance(const SetSourcePlan& source,
                                                       const GridFrame& frame,
                                                       Interrupter* interrupter = nullptr);

}  // namespace nimbus
