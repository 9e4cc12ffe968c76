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
#include "absl/strings/str_cat.h"
#include "core/io/vdb_io.h"

namespace nimbus {

/// File name of the module, looked for in $NIMBUS_VDB_MODULE (a full path),
/// then beside the running program, then in ../lib/nimbus/ from it.
inline constexpr char kVdbModuleName[] = "libnimbus_vdb.so";
/// The one symbol the module exports for the loader.
inline constexpr char kVdbModuleEntry[] = "NimbusVdbModule";
/// Bumped whenever the table below changes, so a stale module is refused
/// rather than called through the wrong slots.
inline constexpr int kVdbModuleAbi = 2;

/// @brief The module's io functions, each the OpenVDB implementation of
/// the public function of the same name in vdb_io.h. Both sides are built
/// together, so C++ types may cross. The families above io keep their own
/// tables, under entries of their own, beside their code
/// (core/matrix/component_vdb_module.h, core/sets/voxelize_vdb_module.h).
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
};

/// The entry's type: returns the module's table (static, never freed).
/// C linkage only so that dlsym finds it by that name.
using VdbModuleEntry = const VdbModule*();

/// The module, loaded on the first call (dlopen, once, thread-safe) and
/// never unloaded; FAILED_PRECONDITION naming every path tried when it is
/// not installed.
absl::StatusOr<const VdbModule*> LoadVdbModule();

/// The module's extern "C" entry `symbol` (a family's table), loaded as
/// LoadVdbModule loads the module; FAILED_PRECONDITION as there.
absl::StatusOr<void*> LoadVdbModuleSymbol(const char* symbol);

/// A family's table from entry `symbol` (a function returning a static
/// `const Table*` whose `abi` must equal `abi`); FAILED_PRECONDITION for a
/// missing module or a stale table. Call it once and keep the result.
template <class Table>
absl::StatusOr<const Table*> LoadVdbModuleTable(const char* symbol, int abi) {
  absl::StatusOr<void*> entry = LoadVdbModuleSymbol(symbol);
  if (!entry.ok()) return entry.status();
  const Table* table = reinterpret_cast<const Table* (*)()>(*entry)();
  if (table == nullptr || table->abi != abi)
    return absl::FailedPreconditionError(absl::StrCat(kVdbModuleName, ": ", symbol,
                                                      " table version ", table ? table->abi : 0,
                                                      ", expected ", abi));
  return table;
}

}  // namespace nimbus
