#include "core/matrix/component_grid.h"

#include "core/base/status_macros.h"
#include "core/io/vdb_module.h"
#include "core/matrix/component_vdb_module.h"

namespace nimbus {

ComponentAccumulator::ComponentAccumulator(Int3 resolution)
    : density_(resolution), best_(resolution), label_plus_one_(resolution) {}

void ComponentAccumulator::Add(int32_t label, const CountGrid& counts) {
  density_.Merge(counts);
  counts.ForEachVoxel([&](Int3 v, uint32_t c) {
    const uint32_t best = best_.Get(v.x, v.y, v.z);
    if (c <= best) return;
    // CountGrid only adds, so store the differences.
    best_.Add(v.x, v.y, v.z, c - best);
    // Counters are modular uint32, so adding the difference also lowers.
    const uint32_t old = label_plus_one_.Get(v.x, v.y, v.z);
    const uint32_t want = uint32_t(label) + 1;
    if (want != old) label_plus_one_.Add(v.x, v.y, v.z, want - old);
  });
}

int32_t ComponentAccumulator::LabelAt(int x, int y, int z) const {
  return int32_t(label_plus_one_.Get(x, y, z)) - 1;
}

std::vector<uint64_t> ComponentAccumulator::VoxelsPerLabel() const {
  std::vector<uint64_t> out;
  ForEachLabel([&](int, int, int, int32_t label) {
    if (size_t(label) >= out.size()) out.resize(size_t(label) + 1, 0);
    ++out[size_t(label)];
  });
  return out;
}

uint64_t ComponentAccumulator::MaxMemoryBytes(Int3 resolution) {
  return 3 * CountGrid::MaxMemoryBytes(resolution);
}

// The label grids are OpenVDB's: written and read in the module.
namespace {

absl::StatusOr<const ComponentVdbTable*> ComponentVdb() {
  static const absl::StatusOr<const ComponentVdbTable*> table =
      LoadVdbModuleTable<ComponentVdbTable>(kComponentVdbEntry, kComponentVdbAbi);
  return table;
}

}  // namespace

absl::Status WriteDensityAndComponentVdb(const std::filesystem::path& path,
                                         const ComponentAccumulator& acc, const GridFrame& frame,
                                         const DensityOptions& options, ComponentGridType type,
                                         const Metadata& metadata,
                                         const std::filesystem::path& int32_path) {
  NIMBUS_ASSIGN_OR_RETURN(const ComponentVdbTable* vdb, ComponentVdb());
  return vdb->write_density_and_component(path, acc, frame, options, type, metadata, int32_path);
}

absl::StatusOr<std::vector<int32_t>> ReadComponentGrid(const std::filesystem::path& path,
                                                       Int3 resolution) {
  NIMBUS_ASSIGN_OR_RETURN(const ComponentVdbTable* vdb, ComponentVdb());
  return vdb->read_component_grid(path, resolution);
}

}  // namespace nimbus
