// The entry of libnimbus_vdb.so (vdb_module.h): the table of the OpenVDB
// implementations. The module sits above every engine family, so this file
// alone may name the matrix and sets functions beside io's.
#include <filesystem>
#include <string>
#include <vector>

#include "core/io/vdb_file.h"
#include "core/io/vdb_impl.h"
#include "core/io/vdb_module.h"
#include "core/matrix/component_grid.h"
#include "core/sets/voxelize.h"

namespace nimbus::vdb_impl {

// component_vdb.cc
absl::Status WriteDensityAndComponentVdb(const std::filesystem::path& path,
                                         const ComponentAccumulator& acc, const GridFrame& frame,
                                         const DensityOptions& options, ComponentGridType type,
                                         const Metadata& metadata,
                                         const std::filesystem::path& int32_path);
absl::StatusOr<std::vector<int32_t>> ReadComponentGrid(const std::filesystem::path& path,
                                                       Int3 resolution);
// voxelize_vdb.cc
absl::StatusOr<VoxelizeResult> VoxelizeMesh(const TriangleMesh& mesh, const GridFrame& frame,
                                            const VoxelizeOptions& options,
                                            Interrupter* interrupter);
absl::Status SaveMeshLevelSet(const TriangleMesh& mesh, const GridFrame& frame,
                              const std::filesystem::path& path, const std::string& grid_name);
absl::StatusOr<VoxelSet> LoadGridSet(const std::filesystem::path& path, const GridFrame& frame,
                                     const GridSetOptions& options, Interrupter* interrupter);

namespace {

VdbModule MakeTable() {
  VdbModule t;
  t.abi = kVdbModuleAbi;
  t.write_density = &WriteDensityVdb;
  t.write_integer_counts = &WriteIntegerCountsVdb;
  t.write_float_volume = &WriteFloatVolumeVdb;
  t.read_integer_counts = &ReadIntegerCountsVdb;
  t.density_bytes = &DensityVdbBytes;
  t.read_file = &ReadVdbFile;
  t.read_bytes = &ReadVdbBytes;
  t.read_vec3_file = &ReadVec3VdbFile;
  t.check_untrusted = &CheckUntrustedVdb;
  t.set_digest_sink = &vdb_internal::SetDigestSink;
  t.write_density_and_component = &WriteDensityAndComponentVdb;
  t.read_component_grid = &ReadComponentGrid;
  t.voxelize_mesh = &VoxelizeMesh;
  t.save_mesh_level_set = &SaveMeshLevelSet;
  t.load_grid_set = &LoadGridSet;
  return t;
}

}  // namespace

}  // namespace nimbus::vdb_impl

extern "C" __attribute__((visibility("default"))) const nimbus::VdbModule* NimbusVdbModule() {
  static const nimbus::VdbModule table = nimbus::vdb_impl::MakeTable();
  return &table;
}
