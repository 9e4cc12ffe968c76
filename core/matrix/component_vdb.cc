// The OpenVDB side of component_grid.h, in the libnimbus_vdb.so module
// (core/io/vdb_module.h): the component label grids and their reader.
#include <openvdb/openvdb.h>

#include "absl/strings/str_cat.h"
#include "core/io/metadata_keys.h"
#include "core/io/vdb_impl.h"
#include "core/io/vdb_internal.h"
#include "core/matrix/component_grid.h"
#include "core/matrix/component_vdb_module.h"

namespace nimbus {

namespace {

template <typename GridT>
typename GridT::Ptr BuildComponentGrid(const ComponentAccumulator& acc, const GridFrame& frame,
                                       const OutputConventions& conventions) {
  using ValueT = typename GridT::ValueType;
  auto grid = GridT::create(ValueT(-1));
  grid->setName("component");
  grid->setGridClass(openvdb::GRID_UNKNOWN);
  // The density's transform and conventions (labels are exact in halves).
  grid->setTransform(vdb_internal::FrameTransform(frame, conventions.up_axis));
  grid->insertMeta(meta_key::kUpAxis,
                   openvdb::StringMetadata(vdb_internal::UpAxisName(conventions.up_axis)));
  grid->setSaveFloatAsHalf(conventions.half_float);
  auto accessor = grid->getAccessor();
  acc.ForEachLabel([&](int x, int y, int z, int32_t label) {
    accessor.setValueOn(openvdb::Coord(x, y, z), ValueT(label));
  });
  vdb_internal::SetFrameMetadata(*grid, frame);
  grid->insertMeta("nimbus_component_labels",
                   openvdb::StringMetadata("selection index of the dominant component; -1 none"));
  return grid;
}

}  // namespace

namespace vdb_impl {

absl::Status WriteDensityAndComponentVdb(const std::filesystem::path& path,
                                         const ComponentAccumulator& acc, const GridFrame& frame,
                                         const DensityOptions& options, ComponentGridType type,
                                         const Metadata& metadata,
                                         const std::filesystem::path& int32_path) {
  if (type == ComponentGridType::kNone)
    return vdb_impl::WriteDensityVdb(path, acc.density(), frame, options, metadata, {});
  // Labels have no box filter; the spec converter refuses this by name.
  if (options.conventions.Downsamples())
    return absl::InvalidArgumentError("a component grid cannot be downsampled");
  vdb_internal::InitOpenVdb();
  const bool side_file = type == ComponentGridType::kInt && !int32_path.empty();
  if (side_file) {
    // Written first, so the side file exists once the result does.
    openvdb::GridPtrVec labels;
    try {
      labels.push_back(BuildComponentGrid<openvdb::Int32Grid>(acc, frame, options.conventions));
    } catch (const std::exception& e) {
      return absl::InternalError(absl::StrCat("writing ", int32_path.string(), ": ", e.what()));
    }
    if (auto st = vdb_internal::WriteGridsAtomically(int32_path, labels); !st.ok()) return st;
  }
  // The density grid comes from vdb_io so both writers agree bit for bit;
  // it is written to a side file, read back and joined with the labels.
  const std::filesystem::path density_tmp = path.string() + ".density.partial";
  if (auto st = vdb_impl::WriteDensityVdb(density_tmp, acc.density(), frame, options, metadata, {});
      !st.ok())
    return st;
  openvdb::GridPtrVecPtr grids;
  std::error_code ec;
  try {
    grids = vdb_internal::ReadAllGrids(density_tmp);
    auto labels = BuildComponentGrid<openvdb::FloatGrid>(acc, frame, options.conventions);
    if (side_file)
      labels->insertMeta("nimbus_component_int32_file",
                         openvdb::StringMetadata(int32_path.filename().string()));
    grids->push_back(labels);
  } catch (const std::exception& e) {
    std::filesystem::remove(density_tmp, ec);
    return absl::InternalError(absl::StrCat("writing ", path.string(), ": ", e.what()));
  }
  std::filesystem::remove(density_tmp, ec);
  return vdb_internal::WriteGridsAtomically(path, *grids);
}

absl::StatusOr<std::vector<int32_t>> ReadComponentGrid(const std::filesystem::path& path,
                                                       Int3 resolution) {
  vdb_internal::InitOpenVdb();
  std::vector<int32_t> out(size_t(resolution.Volume()), -1);
  auto put = [&](const openvdb::Coord& c, int32_t v) -> absl::Status {
    if (c.x() < 0 || c.y() < 0 || c.z() < 0 || c.x() >= resolution.x || c.y() >= resolution.y ||
        c.z() >= resolution.z)
      return absl::DataLossError("component voxel outside the resolution");
    out[(size_t(c.x()) * resolution.y + c.y()) * resolution.z + c.z()] = v;
    return absl::OkStatus();
  };
  try {
    auto grids = vdb_internal::ReadAllGrids(path);
    for (const auto& g : *grids) {
      if (g->getName() != "component") continue;
      if (auto ig = openvdb::gridPtrCast<openvdb::Int32Grid>(g)) {
        for (auto it = ig->cbeginValueOn(); it; ++it)
          if (auto st = put(it.getCoord(), *it); !st.ok()) return st;
        return out;
      }
      if (auto fg = openvdb::gridPtrCast<openvdb::FloatGrid>(g)) {
        for (auto it = fg->cbeginValueOn(); it; ++it)
          if (auto st = put(it.getCoord(), int32_t(*it)); !st.ok()) return st;
        return out;
      }
    }
  } catch (const std::exception& e) {
    return absl::InvalidArgumentError(absl::StrCat("reading ", path.string(), ": ", e.what()));
  }
  return absl::NotFoundError(absl::StrCat(path.string(), ": no grid named 'component'"));
}

}  // namespace vdb_impl

}  // namespace nimbus

extern "C" __attribute__((visibility("default"))) const nimbus::ComponentVdbTable*
NimbusComponentVdb() {
  static const nimbus::ComponentVdbTable table{
      nimbus::kComponentVdbAbi, &nimbus::vdb_impl::WriteDensityAndComponentVdb,
      &nimbus::vdb_impl::ReadComponentGrid};
  return &table;
}
