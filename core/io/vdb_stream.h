// Writing an OpenVDB archive one grid at a time, with the leaf buffers
// encoded in parallel from any source: byte for byte what
// openvdb::io::File::write writes for the same grids, without ever holding
// the grids' voxels. Internal: includes OpenVDB, so only .cc files may
// include it.
#pragma once

#include <openvdb/io/Compression.h>
#include <openvdb/io/DelayedLoadMetadata.h>
#include <openvdb/openvdb.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "core/io/leaf_runs.h"

namespace nimbus::vdb_internal {

/// The archive compression of every Nimbus file.
inline constexpr uint32_t kArchiveCompression =
    openvdb::io::COMPRESS_BLOSC | openvdb::io::COMPRESS_ACTIVE_MASK;

/// @brief One grid ready to be written. `grid` carries the metadata, the
/// transform and the tree's topology: its leaves may be created without
/// buffers (openvdb::PartialCreate), since only their masks are read.
/// `buffers` holds the leaves' encodings, `delayed` what OpenVDB's writer
/// records per leaf for delayed loading.
struct EncodedGrid {
  openvdb::GridBase::Ptr grid;
  LeafRuns buffers;
  openvdb::io::DelayedLoadMetadata::Ptr delayed;
};

/// Makes the next grid of an archive. Producers run one at a time, in file
/// order, so only one grid's encoded leaves are alive at once. `name` is
/// the grid's name, needed before any grid is made to number repeated
/// names as OpenVDB does ("name[0]", "name[1]").
struct GridProducer {
  std::string name;
  std::function<EncodedGrid()> make;
};

/// Writes a whole archive (header, empty file metadata, then each
/// producer's grid) to a seekable stream, as io::File::write would with
/// kArchiveCompression. Throws OpenVDB's exceptions.
void WriteStreamedArchive(std::ostream& os, const std::vector<GridProducer>& grids);

/// WriteGridsAtomically (vdb_internal.h) for produced grids: the archive
/// goes through a temporary file renamed into place, with the same errors.
/// Grids past kSpillKeepBytes of encoded leaves spill beside `path`, unless
/// an enclosing SpillScope names another directory.
absl::Status WriteStreamedAtomically(const std::filesystem::path& path,
                                     const std::vector<GridProducer>& grids);

/// Bytes of a leaf's encoded buffer that OpenVDB's delayed-load metadata
/// counts as compressed (the value block after the mask, the mask-compression
/// byte and the inactive values), given the whole leaf encoding.
int64_t DelayedLoadSize(const std::string& leaf_bytes, size_t value_size);

/// @brief Encodes the leaves of `topology` in tree order, in parallel in the
/// caller's task arena. For each leaf, `fill(const LeafT& topo, LeafT& leaf)`
/// sets the values of a scratch leaf that already has the topology leaf's
/// origin and mask and the background everywhere; then `chunk(const LeafT*
/// leaves, size_t n)` sees every run of filled leaves in tree order, on the
/// calling thread (for sums whose rounding depends on the order). `fill`
/// must be safe to call from several threads at once.
template <typename GridT, typename Fill, typename Chunk>
EncodedGrid EncodeLeaves(typename GridT::Ptr topology, const Fill& fill, const Chunk& chunk) {
  using LeafT = typename GridT::TreeType::LeafNodeType;
  using ValueT = typename LeafT::ValueType;
  EncodedGrid out;
  out.grid = topology;
  out.delayed = std::make_shared<openvdb::io::DelayedLoadMetadata>();
  std::vector<const LeafT*> leaves;
  for (auto it = topology->tree().cbeginLeaf(); it; ++it) leaves.push_back(it.getLeaf());
  const size_t n = leaves.size();
  if (n == 0) return out;
  out.delayed->resizeMask(n);
  out.delayed->resizeCompressedSize(n);
  const ValueT background = topology->tree().background();
  const bool half = topology->saveFloatAsHalf();
  // Chunks bound the scratch leaves; enough leaves per task to amortise it.
  constexpr size_t kChunk = 256;
  const size_t m = std::min(n, kChunk);
  std::unique_ptr<LeafT[]> scratch(new LeafT[m]);
  std::vector<std::string> bytes(m);
  for (size_t first = 0; first < n; first += kChunk) {
    const size_t count = std::min(kChunk, n - first);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, count, 32), [&](const auto& r) {
      std::ostringstream os(std::ios_base::binary);
      openvdb::io::setDataCompression(os, kArchiveCompression);
      openvdb::io::setGridBackgroundValuePtr(os, &background);
      for (size_t j = r.begin(); j < r.end(); ++j) {
        const LeafT& topo = *leaves[first + j];
        LeafT& leaf = scratch[j];
        leaf.setOrigin(topo.origin());
        leaf.buffer().fill(background);
        leaf.setValueMask(topo.getValueMask());
        fill(topo, leaf);
        os.str(std::string());
        leaf.writeBuffers(os, half);
        bytes[j] = os.str();
      }
    });
    size_t run = 0;
    for (size_t j = 0; j < count; ++j) run += bytes[j].size();
    std::string blob;
    blob.reserve(run);
    for (size_t j = 0; j < count; ++j) {
      const std::string& b = bytes[j];
      out.delayed->setMask(first + j, int8_t(b[LeafT::NUM_VALUES / 8]));
      out.delayed->setCompressedSize(first + j, DelayedLoadSize(b, sizeof(ValueT)));
      blob += b;
    }
    out.buffers.Append(std::move(blob));
    chunk(static_cast<const LeafT*>(scratch.get()), count);
  }
  return out;
}

}  // namespace nimbus::vdb_internal
