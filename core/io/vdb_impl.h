// The OpenVDB implementations behind vdb_io.h's functions, inside the
// libnimbus_vdb.so module only (vdb_module.h): same names and signatures
// in namespace vdb_impl, so that the forwarders in namespace nimbus and
// these never clash, even in a test that links both. Call them qualified
// (vdb_impl::…): their arguments' namespace would otherwise find the
// forwarders too.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "core/io/vdb_io.h"

namespace nimbus::vdb_impl {

absl::Status WriteDensityVdb(const std::filesystem::path& path, const CountGrid& counts,
                             const GridFrame& frame, const DensityOptions& options,
                             const Metadata& metadata, const std::vector<Vec3Field>& fields);
absl::Status WriteIntegerCountsVdb(const std::filesystem::path& path, const CountGrid& counts,
                                   const GridFrame& frame, const DensityOptions& options,
                                   const Metadata& metadata);
absl::Status WriteFloatVolumeVdb(const std::filesystem::path& path, const FloatVolume& volume,
                                 const Metadata& metadata, const OutputConventions& conventions);
absl::StatusOr<std::vector<int64_t>> ReadIntegerCountsVdb(const std::filesystem::path& path,
                                                          Int3 resolution);
absl::StatusOr<std::string> DensityVdbBytes(const CountGrid& counts, const GridFrame& frame,
                                            const DensityOptions& options,
                                            const Metadata& metadata);
absl::StatusOr<DenseVolume> ReadVdbFile(const std::filesystem::path& path,
                                        const std::string& name);
absl::StatusOr<DenseVolume> ReadVdbBytes(const std::string& bytes, const std::string& name);
absl::StatusOr<DenseVec3Volume> ReadVec3VdbFile(const std::filesystem::path& path,
                                                const std::string& name);
absl::Status CheckUntrustedVdb(const std::filesystem::path& path,
                               const std::filesystem::path& laundered);

}  // namespace nimbus::vdb_impl
