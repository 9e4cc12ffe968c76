// The io entry of libnimbus_vdb.so (vdb_module.h): the table of io's OpenVDB
// implementations. The matrix and sets families export their own tables
// (component_vdb.cc, voxelize_vdb.cc).
#include <filesystem>
#include <string>
#include <vector>

#include "core/io/vdb_impl.h"
#include "core/io/vdb_module.h"

namespace nimbus::vdb_impl {

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
  return t;
}

}  // namespace

}  // namespace nimbus::vdb_impl

extern "C" __attribute__((visibility("default"))) const nimbus::VdbModule* NimbusVdbModule() {
  static const nimbus::VdbModule table = nimbus::vdb_impl::MakeTable();
  return &table;
}
