// Dense binary voxel sets: the state of a set IFS (condensation sets,
// docs/algorithms.md#maps-that-act-on-sets). Free of OpenVDB.
#pragma once

#include <bit>
#include <cstdint>
#include <optional>
#include <vector>

#include "absl/status/status.h"
#include "core/base/geometry.h"

namespace nimbus {

/// @brief Inclusive integer box of voxel indices.
struct VoxelBox {
  Int3 min, max;  // both inclusive

  Int3 Size() const { return {max.x - min.x + 1, max.y - min.y + 1, max.z - min.z + 1}; }
  int64_t Volume() const { return Size().Volume(); }
  bool Contains(Int3 v) const {
    return v.x >= min.x && v.x <= max.x && v.y >= min.y && v.y <= max.y && v.z >= min.z &&
           v.z <= max.z;
  }
  /// Smallest box holding both.
  static VoxelBox Hull(const VoxelBox& a, const VoxelBox& b);
  friend bool operator==(const VoxelBox& a, const VoxelBox& b) = default;
};

/// Checks that a resolution is usable for a VoxelSet: 1..kMaxSetResolution
/// voxels per axis.
absl::Status ValidateSetResolution(Int3 resolution);

/// Checks a frame for voxel-set work: a valid resolution and finite bounds
/// of positive size.
absl::Status ValidateSetFrame(const GridFrame& frame);

/// @brief A dense bit set over a voxel lattice of a given resolution.
///
/// Voxel (x, y, z) is bit x of row (y, z). Rows are padded to whole 64-bit
/// words so that row scans need no division and word-wise set operations
/// stay aligned; padding bits are always zero. 256^3 voxels take 2 MiB.
class VoxelSet {
 public:
  /// Feature transforms pack coordinates into 10 bits per axis.
  static constexpr int kMaxResolution = 1024;

  VoxelSet() = default;
  /// An empty set. Precondition: ValidateSetResolution(resolution).ok().
  explicit VoxelSet(Int3 resolution);

  Int3 resolution() const { return res_; }
  int words_per_row() const { return words_per_row_; }
  bool InBounds(int x, int y, int z) const {
    return x >= 0 && y >= 0 && z >= 0 && x < res_.x && y < res_.y && z < res_.z;
  }
  bool InBounds(Int3 v) const { return InBounds(v.x, v.y, v.z); }

  /// Word index of the row (y, z).
  size_t RowOffset(int y, int z) const {
    return (size_t(z) * res_.y + size_t(y)) * size_t(words_per_row_);
  }
  const uint64_t* Row(int y, int z) const { return words_.data() + RowOffset(y, z); }
  uint64_t* MutableRow(int y, int z) { return words_.data() + RowOffset(y, z); }
  const std::vector<uint64_t>& words() const { return words_; }
  std::vector<uint64_t>& mutable_words() { return words_; }

  /// Unchecked access; (x, y, z) must be in bounds.
  bool Get(int x, int y, int z) const { return (Row(y, z)[x >> 6] >> (x & 63)) & 1; }
  bool Get(Int3 v) const { return Get(v.x, v.y, v.z); }
  /// Bounds-checked access; out-of-bounds voxels are not members.
  bool Contains(Int3 v) const { return InBounds(v) && Get(v); }
  void Set(int x, int y, int z) { MutableRow(y, z)[x >> 6] |= uint64_t{1} << (x & 63); }
  void Set(Int3 v) { Set(v.x, v.y, v.z); }
  void Reset(int x, int y, int z) { MutableRow(y, z)[x >> 6] &= ~(uint64_t{1} << (x & 63)); }
  /// Sets voxels x0..x1 (inclusive) of row (y, z).
  void SetSpan(int x0, int x1, int y, int z);

  /// Empties the set (keeps the resolution).
  void Clear();
  /// Makes every voxel a member.
  void Fill();

  int64_t Count() const;
  bool Empty() const;
  /// Tight box around the members, or nullopt for an empty set.
  std::optional<VoxelBox> BoundingBox() const;

  /// In-place set algebra; `other` must have the same resolution.
  VoxelSet& operator|=(const VoxelSet& other);
  VoxelSet& operator&=(const VoxelSet& other);
  VoxelSet& operator-=(const VoxelSet& other);  // set difference
  friend VoxelSet operator|(VoxelSet a, const VoxelSet& b) { return a |= b; }
  friend VoxelSet operator&(VoxelSet a, const VoxelSet& b) { return a &= b; }
  friend VoxelSet operator-(VoxelSet a, const VoxelSet& b) { return a -= b; }
  friend bool operator==(const VoxelSet& a, const VoxelSet& b) {
    return a.res_ == b.res_ && a.words_ == b.words_;
  }

  /// Calls f(x, y, z) for every member, z slowest and x fastest.
  template <typename F>
  void ForEach(F&& f) const {
    ForEachInSlabs(0, res_.z, f);
  }
  /// As ForEach, restricted to slices z0 <= z < z1 (for parallel loops).
  template <typename F>
  void ForEachInSlabs(int z0, int z1, F&& f) const {
    for (int z = z0; z < z1; ++z)
      for (int y = 0; y < res_.y; ++y) {
        const uint64_t* row = Row(y, z);
        for (int w = 0; w < words_per_row_; ++w)
          for (uint64_t bits = row[w]; bits; bits &= bits - 1)
            f((w << 6) + std::countr_zero(bits), y, z);
      }
  }

  size_t MemoryBytes() const { return words_.size() * sizeof(uint64_t); }

 private:
  Int3 res_;
  int words_per_row_ = 0;
  std::vector<uint64_t> words_;
};

/// Members of `set` moved by an integer voxel offset; voxels leaving the
/// lattice are dropped.
VoxelSet ShiftSet(const VoxelSet& set, Int3 offset);

/// Members whose 6-neighbourhood leaves the set (lattice edges count as
/// outside): the only voxels that can be nearest to a point outside the set.
VoxelSet BoundaryOf(const VoxelSet& set);

}  // namespace nimbus
