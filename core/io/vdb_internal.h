// OpenVDB helpers shared by the .cc files of the libnimbus_vdb.so module
// (vdb_module.h), and by tests that link it. This header includes OpenVDB,
// so only those .cc files may include it, never a public header.
#pragma once

#include <openvdb/openvdb.h>

#include <filesystem>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "core/base/geometry.h"
#include "core/io/vdb_file.h"  // SetWriteFaultForTesting, StampContentUuid
#include "core/io/vdb_io.h"

namespace nimbus::vdb_internal {

/// openvdb::initialize(), once per process.
void InitOpenVdb();
/// The transform of a GridFrame: voxel centres at integer index coordinates,
/// then world space rotated so the spec's +Y is +Z for UpAxis::kZ.
openvdb::math::Transform::Ptr FrameTransform(const GridFrame& frame, UpAxis up = UpAxis::kY);
/// Metadata nimbus_up_axis: "Y" or "Z".
const char* UpAxisName(UpAxis up);
/// Records the frame (nimbus_resolution, nimbus_bounds_min/max) on a grid,
/// so readers can rebuild the dense lattice.
void SetFrameMetadata(openvdb::GridBase& grid, const GridFrame& frame);
/// Every grid of a .vdb file. Throws OpenVDB's exceptions; callers turn
/// them into statuses.
openvdb::GridPtrVecPtr ReadAllGrids(const std::filesystem::path& path);
/// Writes `grids` with OpenVDB's archive writer (Blosc and active-mask
/// compression) to `path` + ".partial", checking every write,
/// fsyncs it, checks its size, stamps the content UUID and renames it into
/// place, so readers never see a half-written file. A full disk (ENOSPC,
/// EDQUOT) is RESOURCE_EXHAUSTED "disk full while writing the result: …";
/// other failures INTERNAL. Removes the partial file on failure.
absl::Status WriteGridsAtomically(const std::filesystem::path& path,
                                  const openvdb::GridPtrVec& grids);

}  // namespace nimbus::vdb_internal
