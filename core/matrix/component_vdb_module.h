// The matrix family's part of libnimbus_vdb.so (core/io/vdb_module.h): the
// label grids of component_grid.h, written and read through OpenVDB in
// component_vdb.cc, which exports this table under its own entry.
#pragma once

#include <cstdint>
#include <filesystem>
#include <vector>

#include "absl/status/statusor.h"
#include "core/matrix/component_grid.h"

namespace nimbus {

inline constexpr char kComponentVdbEntry[] = "NimbusComponentVdb";
/// Bumped whenever the table below changes.
inline constexpr int kComponentVdbAbi = 1;

/// @brief The OpenVDB implementations of component_grid.h's functions of
/// the same name.
struct ComponentVdbTable {
  int abi = 0;
  absl::Status (*write_density_and_component)(const std::filesystem::path&,
                                              const ComponentAccumulator&, const GridFrame&,
                                              const DensityOptions&, ComponentGridType,
                                              const Metadata&, const std::filesystem::path&);
  absl::StatusOr<std::vector<int32_t>> (*read_component_grid)(const std::filesystem::path&, Int3);
};

}  // namespace nimbus
