// OpenVDB helpers shared by core's .cc files. This header includes OpenVDB,
// so only .cc files may include it, never a public header.
#pragma once

#include <openvdb/openvdb.h>

#include <filesystem>

#include "core/geometry.h"

namespace nimbus::vdb_internal {

/// openvdb::initialize(), once per process.
void InitOpenVdb();
/// The transform of a GridFrame: voxel centres at integer index coordinates.
openvdb::math::Transform::Ptr FrameTransform(const GridFrame& frame);
/// Records the frame (nimbus_resolution, nimbus_bounds_min/max) on a grid,
/// so readers can rebuild the dense lattice.
void SetFrameMetadata(openvdb::GridBase& grid, const GridFrame& frame);
/// Every grid of a .vdb file. Throws OpenVDB's exceptions; callers turn
/// them into statuses.
openvdb::GridPtrVecPtr ReadAllGrids(const std::filesystem::path& path);

}  // namespace nimbus::vdb_internal
