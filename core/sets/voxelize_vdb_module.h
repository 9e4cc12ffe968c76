// The sets family's part of libnimbus_vdb.so (core/io/vdb_module.h): mesh
// voxelisation and grid sets of voxelize.h, through OpenVDB in
// voxelize_vdb.cc, which exports this table under its own entry.
#pragma once

#include <filesystem>
#include <string>

#include "absl/status/statusor.h"
#include "core/sets/voxelize.h"

namespace nimbus {

inline constexpr char kVoxelizeVdbEntry[] = "NimbusVoxelizeVdb";
/// Bumped whenever the table below changes.
inline constexpr int kVoxelizeVdbAbi = 1;

/// @brief The OpenVDB implementations of voxelize.h's functions of the
/// same name.
struct VoxelizeVdbTable {
  int abi = 0;
  absl::StatusOr<VoxelizeResult> (*voxelize_mesh)(const TriangleMesh&, const GridFrame&,
                                                  const VoxelizeOptions&, Interrupter*);
  absl::Status (*save_mesh_level_set)(const TriangleMesh&, const GridFrame&,
                                      const std::filesystem::path&, const std::string&);
  absl::StatusOr<VoxelSet> (*load_grid_set)(const std::filesystem::path&, const GridFrame&,
                                            const GridSetOptions&, Interrupter*);
};

}  // namespace nimbus
