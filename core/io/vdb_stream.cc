#include "core/io/vdb_stream.h"

#include <openvdb/io/Archive.h>
#include <openvdb/io/GridDescriptor.h>
#include <openvdb/tools/Count.h>

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <map>
#include <set>
#include <utility>

namespace nimbus::vdb_internal {

namespace {

using openvdb::io::GridDescriptor;
using openvdb::io::StreamMetadata;

// The steps of openvdb::io::Archive::write (OpenVDB 10) that are protected,
// replayed around grids whose leaf buffers come already encoded.
class StreamedArchive : public openvdb::io::Archive {
 public:
  StreamedArchive() { setCompression(kArchiveCompression); }

  void Write(std::ostream& os, const std::vector<GridProducer>& producers) const {
    // The file-level stream state, as Archive::write sets it.
    StreamMetadata::Ptr file_meta(new StreamMetadata);
    openvdb::io::setStreamMetadataPtr(os, file_meta, /*transfer=*/false);
    openvdb::io::setDataCompression(os, compression());
    openvdb::io::setWriteGridStatsMetadata(os, isGridStatsMetadataEnabled());
    writeHeader(os, /*seekable=*/true);
    openvdb::MetaMap().writeMeta(os);
    const int32_t count = int32_t(producers.size());
    os.write(reinterpret_cast<const char*>(&count), sizeof(count));
    std::map<std::string, int> repeats;
    for (const GridProducer& p : producers) ++repeats[p.name];
    std::set<std::string> used;
    for (const GridProducer& produce : producers) {
      const EncodedGrid g = produce.make();
      GridDescriptor gd(UniqueName(produce.name, repeats, used), g.grid->type(),
                        g.grid->saveFloatAsHalf());
      WriteGrid(gd, g, os);
      // Archive::writeGrid restores the file-level stream metadata.
      openvdb::io::setStreamMetadataPtr(os, file_meta, /*transfer=*/false);
      openvdb::io::setDataCompression(os, compression());
    }
  }

 private:
  // Archive::write's numbering of repeated or empty names: "name[n]".
  static std::string UniqueName(const std::string& name, std::map<std::string, int>& repeats,
                                std::set<std::string>& used) {
    std::string unique = name;
    if (name.empty() || repeats[name] > 1) unique = GridDescriptor::addSuffix(name, 0);
    for (int n = 1; used.count(unique) > 0; ++n) unique = GridDescriptor::addSuffix(name, n);
    used.insert(unique);
    return unique;
  }

  // Archive::writeGrid, with the delayed-load metadata and the leaf
  // buffers taken from `g` instead of computed from loaded leaves.
  void WriteGrid(GridDescriptor& gd, const EncodedGrid& g, std::ostream& os) const {
    const openvdb::GridBase& grid = *g.grid;
    StreamMetadata::Ptr meta(new StreamMetadata(*openvdb::io::getStreamMetadataPtr(os)));
    meta->setHalfFloat(grid.saveFloatAsHalf());
    meta->gridMetadata() = static_cast<const openvdb::MetaMap&>(grid);
    openvdb::io::setStreamMetadataPtr(os, meta, /*transfer=*/false);
    gd.writeHeader(os);
    const int64_t offset_pos = int64_t(os.tellp());
    gd.writeStreamPos(os);
    gd.setGridPos(os.tellp());
    setGridCompression(os, grid);
    // A shallow copy (it shares the tree) takes the file's metadata.
    const auto copy = openvdb::ConstPtrCast<openvdb::GridBase>(grid.copyGrid());
    copy->insertMeta(openvdb::GridBase::META_FILE_DELAYED_LOAD, *g.delayed);
    if (openvdb::io::getWriteGridStatsMetadata(os)) {
      copy->addStatsMetadata();
      // The leaves may have no buffers: count them as loaded, as the
      // writer of full leaves does.
      copy->removeMeta(openvdb::GridBase::META_FILE_MEM_BYTES);
      copy->insertMeta(openvdb::GridBase::META_FILE_MEM_BYTES,
                       openvdb::Int64Metadata(int64_t(MemUsageIfLoaded(grid))));
      copy->insertMeta(openvdb::GridBase::META_FILE_COMPRESSION,
                       openvdb::StringMetadata(openvdb::io::compressionToString(
                           openvdb::io::getDataCompression(os))));
    }
    copy->writeMeta(os);
    grid.writeTransform(os);
    grid.writeTopology(os);
    gd.setBlockPos(os.tellp());
    g.buffers.WriteTo(os);
    gd.setEndPos(os.tellp());
    os.seekp(offset_pos, std::ios_base::beg);
    gd.writeStreamPos(os);
    gd.seekToEnd(os);
  }

  template <typename GridT>
  static bool AddMemUsage(const openvdb::GridBase& grid, openvdb::Index64& bytes) {
    if (!grid.isType<GridT>()) return false;
    bytes = openvdb::tools::memUsageIfLoaded(static_cast<const GridT&>(grid).tree());
    return true;
  }
  // The types Nimbus writes; others count as they are in memory.
  static openvdb::Index64 MemUsageIfLoaded(const openvdb::GridBase& grid) {
    openvdb::Index64 bytes = 0;
    if (AddMemUsage<openvdb::FloatGrid>(grid, bytes) ||
        AddMemUsage<openvdb::Int64Grid>(grid, bytes) ||
        AddMemUsage<openvdb::Vec3SGrid>(grid, bytes))
      return bytes;
    return grid.memUsage();
  }
};

}  // namespace

void WriteStreamedArchive(std::ostream& os, const std::vector<GridProducer>& grids) {
  StreamedArchive().Write(os, grids);
}

int64_t DelayedLoadSize(const std::string& leaf_bytes, size_t value_size) {
  namespace io = openvdb::io;
  // Layout of LeafNode::writeBuffers: the value mask (64 bytes), the
  // mask-compression byte, up to two inactive values and a selection mask,
  // then the value block that io::writeCompressedValuesSize measures.
  constexpr size_t kMask = 64;
  const int8_t how = int8_t(leaf_bytes[kMask]);
  size_t extra = 0;
  if (how == io::NO_MASK_AND_ONE_INACTIVE_VAL) extra = value_size;
  if (how == io::MASK_AND_NO_INACTIVE_VALS) extra = kMask;
  if (how == io::MASK_AND_ONE_INACTIVE_VAL) extra = value_size + kMask;
  if (how == io::MASK_AND_TWO_INACTIVE_VALS) extra = 2 * value_size + kMask;
  const size_t block = leaf_bytes.size() - kMask - 1 - extra;
  // An empty half-float block writes nothing, but OpenVDB records its
  // 8-byte length prefix all the same.
  return int64_t(block == 0 ? 8 : block);
}

}  // namespace nimbus::vdb_internal
