// IFS matrices (recurrent, graph-directed IFS): the matrix of map sets, the
// boolean pattern of its non-empty entries, and the checks every use needs
// (aperiodicity, component selection). docs/algorithms.md#components-and-the-matrix-equation;
// docs/ifs_matrices.md.
//
// Conventions used throughout:
//  * indices are 0-based (the reference description counts from 1: its A_12 is our
//    (0, 1));
//  * an entry H_ij is a sorted set of indices into a shared map table;
//  * "f after g" is written f o g and means f(g(p)), as in Affine3;
//  * component (i, j) of the attractor matrix is
//      A_ij = lim_{m->inf} (H^m)_ij (K),  (H^m)_ij = { f1 o ... o fm : f1 in
//      H_{i k1}, f2 in H_{k1 k2}, ..., fm in H_{k(m-1) j} },
//    i.e. the limit of images under words read along graph paths i -> j.
#pragma once

#include <cstdint>
#include <string_view>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"

namespace nimbus {

// ---------------------------------------------------------------------------
// Matrices
// ---------------------------------------------------------------------------

/// A cell of an IFS matrix (and a component of its attractor matrix).
struct Component {
  uint32_t row = 0;
  uint32_t col = 0;
  friend bool operator==(Component a, Component b) = default;
};

/// @brief An n x n matrix whose entries are finite, possibly empty, sets of
/// map-table indices, kept sorted and free of duplicates.
class IfsMatrix {
 public:
  using Entry = std::vector<uint32_t>;

  IfsMatrix() = default;
  explicit IfsMatrix(uint32_t n) : n_(n), entries_(size_t{n} * n) {}
  /// Square rows of entries; InvalidArgument if not square.
  static absl::StatusOr<IfsMatrix> FromRows(const std::vector<std::vector<Entry>>& rows);

  uint32_t size() const { return n_; }
  const Entry& at(uint32_t i, uint32_t j) const { return entries_[size_t{i} * n_ + j]; }
  bool empty(uint32_t i, uint32_t j) const { return at(i, j).empty(); }
  /// Replaces an entry (sorted and de-duplicated here).
  void Set(uint32_t i, uint32_t j, Entry maps);
  void Insert(uint32_t i, uint32_t j, uint32_t map);
  /// Sum of entry sizes: the matrix's cost measure.
  uint64_t MapReferences() const;

  friend bool operator==(const IfsMatrix&, const IfsMatrix&) = default;

 private:
  uint32_t n_ = 0;
  std::vector<Entry> entries_;  // row-major
};

/// OK iff every index of `m` is in `table`; otherwise InvalidArgument naming
/// the matrix, the cell and the index.
absl::Status ValidateMatrix(const IfsMatrix& m, size_t table_size, std::string_view name);

/// @brief A square boolean matrix stored as 64-bit row words, for the
/// pattern R of non-empty entries and its powers.
class BoolMatrix {
 public:
  BoolMatrix() = default;
  explicit BoolMatrix(uint32_t n) : n_(n), words_((n + 63) / 64), bits_(size_t{n} * words_) {}
  static BoolMatrix PatternOf(const IfsMatrix& m);

  uint32_t size() const { return n_; }
  bool Get(uint32_t i, uint32_t j) const {
    return (bits_[size_t{i} * words_ + j / 64] >> (j % 64)) & 1;
  }
  void Set(uint32_t i, uint32_t j, bool v = true);
  /// Boolean product: (A B)_ij = OR_k A_ik AND B_kj.
  friend BoolMatrix operator*(const BoolMatrix& a, const BoolMatrix& b);
  friend bool operator==(const BoolMatrix&, const BoolMatrix&) = default;

 private:
  uint32_t n_ = 0;
  uint32_t words_ = 0;
  std::vector<uint64_t> bits_;
};

// ---------------------------------------------------------------------------
// Aperiodicity and the limit pattern
// ---------------------------------------------------------------------------

/// Where the powers R, R^2, R^3, ... of a boolean matrix settle.
struct PowerAnalysis {
  /// R^k for every k >= index (meaningful when aperiodic).
  BoolMatrix limit;
  /// Smallest m with R^m == R^(m+1) (aperiodic only), else 0.
  uint64_t index = 0;
  /// Cycle length of the power sequence; 1 = aperiodic; 0 = longer than the
  /// search cap (certainly periodic).
  uint64_t period = 1;
  bool aperiodic() const { return period == 1; }
};

/// @brief Finds the cycle the powers of R fall into. The sequence is
/// eventually periodic and its transient (index) is at most (n-1)^2 + 1
/// for any n x n boolean matrix, so R^K with K = n^2 + 1 (reached by
/// repeated squaring) is already on the cycle; the cycle length is then the
/// first t with R^(K+t) == R^K, and aperiodicity is R^(K+1) == R^K.
PowerAnalysis AnalyzePowers(const BoolMatrix& r);

/// The limit pattern lim R^k of an aperiodic matrix: (i, j) set iff the
/// component A_ij is non-empty. InvalidArgument naming `name` (and the
/// period) when the matrix is not aperiodic, or has size 0.
absl::StatusOr<BoolMatrix> AperiodicLimitPattern(const IfsMatrix& m, std::string_view name);
/// Same check, status only.
absl::Status CheckAperiodic(const IfsMatrix& m, std::string_view name);

/// OK iff `selection` is non-empty and every component is in range and
/// non-empty in `limit`; InvalidArgument naming the matrix and component.
absl::Status CheckSelection(const BoolMatrix& limit, const std::vector<Component>& selection,
                            std::string_view name);

}  // namespace nimbus
