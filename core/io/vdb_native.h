// An OpenVDB archive written with no OpenVDB: the pieces of a .vdb file
// (header, grid descriptors, metadata, transform, topology and Blosc leaf
// buffers) encoded by hand, byte for byte as OpenVDB 10's io::File::write
// writes the grids Nimbus makes: float, Vec3f and int64 trees of 5-4-3
// nodes, fog volumes (zero background, inactive voxels zero), non-negative
// voxel coordinates, Blosc + active-mask compression, optionally half
// floats. Tests compare every piece with OpenVDB's own writer.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <ostream>
#include <string>
#include <utility>
#include <vector>

#include "core/base/zero_pages.h"
#include "core/io/leaf_runs.h"

namespace nimbus::vdb_native {

/// IEEE 754 binary16 from a float, rounding to nearest even (overflow to
/// infinity, NaN kept quiet): what OpenVDB's half conversion gives.
uint16_t FloatToHalf(float f);

/// The value types of the grids Nimbus writes.
enum class ValueKind { kFloat, kVec3f, kInt64 };

/// Bytes of one value of `kind` in memory (float 4, Vec3f 12, int64 8).
size_t ValueBytes(ValueKind kind);

/// Appends `n` bytes compressed as io::bloscToStream does (LZ4, level 9,
/// shuffle of 4-byte items, one block), after their int64 size; a negative
/// size and the raw bytes when Blosc cannot compress them.
void BloscToStream(const char* data, size_t n, std::string& out);

/// A leaf's value mask: 512 bits, bit i for voxel i = x*64 + y*8 + z.
using LeafMask = std::array<uint64_t, 8>;

/// @brief Appends one leaf's buffer as LeafNode::writeBuffers writes it
/// when every inactive voxel holds the zero background: the value mask,
/// the mask-compression byte (0: no inactive value to record), then the
/// active values (`count` of them, packed in voxel order, `active`) as
/// halves when `half` and the kind is real, through Blosc. Returns the
/// size OpenVDB's delayed-load metadata records for the leaf.
int64_t EncodeLeaf(ValueKind kind, bool half, const LeafMask& mask, const void* active,
                   size_t count, std::string& out);

/// @brief A grid's metadata (MetaMap::writeMeta): entries sorted by name,
/// each name, type name, int32 size and value. Setting a name again
/// replaces its value, as insertMeta does.
class MetaMap {
 public:
  void String(const std::string& key, const std::string& value);
  void Int64(const std::string& key, int64_t value);
  void Double(const std::string& key, double value);
  void Bool(const std::string& key, bool value);
  void Vec3i(const std::string& key, int32_t x, int32_t y, int32_t z);
  void Vec3d(const std::string& key, double x, double y, double z);
  void Raw(const std::string& key, const std::string& type, std::string bytes);
  void Write(std::string& out) const;

 private:
  std::map<std::string, std::pair<std::string, std::string>> entries_;
};

/// @brief A linear transform as math::Transform::createLinearTransform(m)
/// makes it from the row-vector matrix `m` (p' = p * m): simplified to a
/// (uniform) scale, (uniform) scale-translate or kept affine, as OpenVDB
/// decides with its tolerances.
struct LinearTransform {
  double m[4][4];
  /// Transform::write: the map's type name, then its values.
  std::string Bytes() const;
  /// GridBase::voxelSize() of the grid that carries it.
  std::array<double, 3> VoxelSize() const;
};

/// One leaf of a grid's topology.
struct Leaf {
  std::array<int32_t, 3> origin;  // multiples of 8, non-negative
  LeafMask mask;
};

/// A grid's leaves. From 1 MiB on they come from the kernel in huge pages
/// (ZeroPageAllocator): a 2D picture's 16 384 leaves are 1.3 MB, some 320
/// page faults on a fresh heap.
using LeafList = std::vector<Leaf, ZeroPageAllocator<Leaf>>;

/// Orders leaves as OpenVDB's tree iterates them (root children by origin,
/// then internal-node child index at each level): the file's leaf order.
void SortTreeOrder(LeafList& leaves);

/// @brief One grid to write: what its header, metadata and topology need
/// plus its encoded leaf buffers (`leaves` in tree order, shared by the
/// grids of one result, `buffers` their encodings in that order,
/// `delayed_*` one entry per leaf).
struct Grid {
  std::string name;
  ValueKind kind = ValueKind::kFloat;
  bool half = false;
  MetaMap meta;  // the grid's own metadata; the writer adds the file_* entries
  LinearTransform transform{};
  std::shared_ptr<const LeafList> leaves = std::make_shared<LeafList>();
  vdb_internal::LeafRuns buffers;
  std::vector<int8_t> delayed_mask;
  std::vector<int64_t> delayed_size;
  uint64_t active_voxels = 0;
};

/// @brief Encodes every leaf of `g` (its `leaves`, in tree order) in
/// parallel: `fill(leaf, packed)` writes the leaf's active values
/// (`ValueBytes` each, in voxel order, as many as its mask has bits), then
/// `visit(leaf, packed, count)` sees them on the calling thread in tree
/// order (for order-dependent sums). `fill` may run on several threads.
void EncodeLeaves(Grid& g, const std::function<void(const Leaf&, void*)>& fill,
                  const std::function<void(const Leaf&, const void*, size_t)>& visit);

/// Makes the next grid of an archive; grids are made one at a time, in
/// file order, so only one grid's encoded leaves are alive at once.
struct GridSource {
  std::string name;
  std::function<Grid()> make;
};

/// Writes a whole archive (header, empty file metadata, then each grid) to
/// a seekable stream, as io::File::write writes the same grids. The UUID
/// is a placeholder for vdb_internal::StampContentUuid. Throws
/// std::exception on failure.
void WriteArchive(std::ostream& os, const std::vector<GridSource>& grids);

}  // namespace nimbus::vdb_native
