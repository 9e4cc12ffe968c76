// @brief What building a set source costs in memory, for a server's
// admission before the job runs (the sources themselves: set_source.h).
#pragma once

#include <cstdint>

#include "core/base/geometry.h"
#include "core/io/mesh_io.h"
#include "core/sets/set_source.h"

namespace nimbus {

/// Peak bytes VoxelizeMesh may hold for `mesh` after `placement` on `frame`
/// with `threads` threads: its copies of the mesh and topology, the ray
/// vote's sets and crossings (each triangle meets at most area + perimeter
/// / 2 + 1 lattice rays of an axis, in voxels), and meshToVolume's narrow
/// band around every triangle (at most the grid once per thread). Copies of
/// one triangle cost each time: the price of a small file that fans out.
uint64_t VoxelizeMemoryBytes(const TriangleMesh& mesh, const Affine3& placement,
                             const GridFrame& frame, double shell_voxels, int threads);

/// Peak bytes of building `source` on `frame` with `threads` threads beyond
/// the sets it yields: the largest of its meshes' VoxelizeMemoryBytes,
/// placed as BuildSetSource places them (0 without meshes).
uint64_t SetSourceBuildBytes(const SetSourcePlan& source, const GridFrame& frame, int threads);

}  // namespace nimbus
