// OpenVDB helpers shared by core's .cc files. This header includes OpenVDB,
// so only .cc files may include it, never a public header.
#pragma once

#include <openvdb/openvdb.h>

#include "core/geometry.h"

namespace nimbus::vdb_internal {

/// openvdb::initialize(), once per process.
void InitOpenVdb();
/// The transform of a GridFrame: voxel centres at integer index coordinates.
openvdb::math::Transform::Ptr FrameTransform(const GridFrame& frame);

}  // namespace nimbus::vdb_internal
