// Chaos-game results written with no OpenVDB (vdb_native.h): the density
// and its optional grids, straight from the count tiles, byte for byte
// the file the OpenVDB module writes for the same result. Downsampled
// results and vector fields outside the grid still go through the module.
#pragma once

#include <filesystem>
#include <vector>

#include "absl/status/status.h"
#include "core/io/vdb_io.h"

namespace nimbus::vdb_native {

/// Whether WriteDensityVdb below can write this result: no downsampling,
/// and every field voxel at non-negative coordinates.
bool CanWriteResult(const CountGrid& counts, const DensityOptions& options,
                    const std::vector<Vec3Field>& fields = {});

/// nimbus::WriteDensityVdb without OpenVDB; requires CanWriteResult.
absl::Status WriteDensityVdb(const std::filesystem::path& path, const CountGrid& counts,
                             const GridFrame& frame, const DensityOptions& options,
                             const Metadata& metadata, const std::vector<Vec3Field>& fields);

/// nimbus::WriteIntegerCountsVdb without OpenVDB; requires CanWriteResult
/// for the options it writes with (see the definition).
absl::Status WriteIntegerCountsVdb(const std::filesystem::path& path, const CountGrid& counts,
                                   const GridFrame& frame, const DensityOptions& options,
                                   const Metadata& metadata);

/// The options WriteIntegerCountsVdb writes a result's exact counts with.
DensityOptions IntegerCountsOptions(const DensityOptions& options);

}  // namespace nimbus::vdb_native
