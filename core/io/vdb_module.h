// Everything that needs OpenVDB lives in its own module, libnimbus_vdb.so,
// loaded on first use: libopenvdb.so and its dependencies (log4cplus,
// blosc, boost iostreams) cost every process some 60 ms of dynamic linking
// at start-up, which `nimbus --help`, `nimbus list` and every job that
// writes no VDB would pay for nothing. The public headers (vdb_io.h,
// component_grid.h, voxelize.h) keep their functions; their definitions
// here in core forward to the module's table, and report a missing module
// as a status naming the paths tried.
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "core/io/vdb_io.h"

namespace nimbus {

// Types of the engine families above io (matrix, sets), declared here only
// so that the table can name them.
class ComponentAccumulator;
enum class ComponentGridType;
struct TriangleMesh;
struct VoxelizeOptions;
struct VoxelizeResult;
struct GridSetOptions;
class VoxelSet;
class Interrupter;

/// File name of the module, looked for in $NIMBUS_VDB_MODULE (a full path),
/// then beside the running program, then in ../lib/nimbus/ from it.
inline constexpr char kVdbModuleName[] = "libnimbus_vdb.so";
/// The one symbol the module exports for the loader.
inline constexpr char kVdbModuleEntry[] = "NimbusVdbModule";
/// Bumped whenever the table below changes, so a stale module is refused
/// rather than called through the wrong slots.
inline constexpr int kVdbModuleAbi = 2;

/// @brief The module's functions, each the OpenVDB implementation of the
/// public function of the same name (vdb_io.h, component_grid.h,
/// voxelize.h). Both sides are built together, so C++ types may cross.
struct VdbModule {
  int abi = 0;
  absl::Status (*write_density)(const std::filesystem::path&, const CountGrid&,
                                const GridFrame&, const DensityOptions&, const Metadata&,
                                const std::vector<Vec3Field>&);
  absl::Status (*write_integer_counts)(const std::filesystem::path&, const CountGrid&,
                                       const GridFrame&, const DensityOptions&,
                                       const Metadata&);
  absl::Status (*write_float_volume)(const std::filesystem::path&, const FloatVolume&,
                                     const Metadata&, const OutputConventions&);
  absl::StatusOr<std::vector<int64_t>> (*read_integer_counts)(const std::filesystem::path&,
                                                              Int3);
  absl::StatusOr<std::string> (*density_bytes)(const CountGrid&, const GridFrame&,
                                               const DensityOptions&, const Metadata&);
  absl::StatusOr<DenseVolume> (*read_file)(const std::filesystem::path&, const std::string&);
  absl::StatusOr<DenseVolume> (*read_bytes)(const std::string&, const std::string&);
  absl::StatusOr<DenseVec3Volume> (*read_vec3_file)(const std::filesystem::path&,
                                                    const std::string&);
  absl::Status (*check_untrusted)(const std::filesystem::path&, const std::filesystem::path&);
  /// Where the module's writers record the digests of the files they
  /// write: the loader passes its own RememberFileSha256 (vdb_file.h).
  void (*set_digest_sink)(void (*)(int fd, const std::string& sha256));
  // core/matrix/component_grid.h
  absl::Status (*write_density_and_component)(const std::filesystem::path&,
                                              const ComponentAccumulator&, const GridFrame&,
                                              const DensityOptions&, ComponentGridType,
                                              const Metadata&, const std::filesystem::path&);
  absl::StatusOr<std::vector<int32_t>> (*read_component_grid)(const std::filesystem::path&,
                                                              Int3);
  // core/sets/voxelize.h
  absl::StatusOr<VoxelizeResult> (*voxelize_mesh)(const TriangleMesh&, const GridFrame&,
                                                  const VoxelizeOptions&, Interrupter*);
  absl::Status (*save_mesh_level_set)(const TriangleMesh&, const GridFrame&,
                                      const std::filesystem::path&, const std::string&);
  absl::StatusOr<VoxelSet> (*load_grid_set)(const std::filesystem::path&, const GridFrame&,
                                            const GridSetOptions&, Interrupter*);
};

/// The entry's type: returns the module's table (static, never freed).
/// C linkage only so that dlsym finds it by that name.
using VdbModuleEntry = const VdbModule*();

/// The module, loaded on the first call (dlopen, once, thread-safe) and
/// never unloaded; FAILED_PRECONDITION naming every path tried when it is
/// not installed.
absl::StatusOr<const VdbModule*> LoadVdbModule();

}  // namespace nimbus
