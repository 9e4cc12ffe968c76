// The map table that IFS matrices index: base maps plus the compositions
// that matrix operations create (docs/ifs_matrices.md).
#pragma once

#include <cstdint>
#include <map>
#include <string_view>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/chaos/point_map.h"

namespace nimbus {

/// @brief The growing, append-only table of point maps that IFS matrices
/// index. Every entry carries its *word*: the sequence of base maps it is
/// the composition of (outermost first; the identity map has the empty
/// word). Composition is memoised by word, so f o (g o h) and (f o g) o h
/// share one entry and set operations on entries compare words, not floats.
///
/// Composition is concrete (a new PointMap the engine can run), not
/// symbolic, and therefore restricted to what a PointMap can express
/// exactly: the OUTER map f must have no variations (it may have a post
/// affine, which then just folds in). Affine after affine multiplies the
/// affines; affine after nonlinear g becomes g with f folded into g's post.
/// Nonlinear after anything is refused, naming the map, because variations
/// read their own pre-affine's coefficients and cannot absorb an inner map.
class MapTable {
 public:
  MapTable() = default;
  /// The base maps get the one-letter words {0}, {1}, ...
  explicit MapTable(std::vector<PointMap> base_maps);

  size_t size() const { return maps_.size(); }
  size_t base_size() const { return base_size_; }
  const std::vector<PointMap>& maps() const { return maps_; }
  const PointMap& map(uint32_t index) const { return maps_[index]; }
  /// Base-map letters of entry `index`, outermost first.
  const std::vector<uint32_t>& word(uint32_t index) const { return words_[index]; }
  bool IsIdentity(uint32_t index) const { return words_[index].empty(); }

  /// Index of the first map called `name`; NotFound lists the known names.
  absl::StatusOr<uint32_t> Find(std::string_view name) const;

  /// Index of the identity map (named "identity"), appended on first use.
  absl::StatusOr<uint32_t> Identity();

  /// Index of f o g (f after g), appending it unless its word exists.
  /// Identity is neutral. Errors: OutOfRange for a bad index,
  /// InvalidArgument when f is nonlinear, ResourceExhausted beyond
  /// max_maps().
  absl::StatusOr<uint32_t> Compose(uint32_t f, uint32_t g);

  void set_max_maps(size_t max_maps) { max_maps_ = max_maps; }
  size_t max_maps() const { return max_maps_; }

 private:
  absl::StatusOr<uint32_t> Append(PointMap map, std::vector<uint32_t> word);

  std::vector<PointMap> maps_;
  std::vector<std::vector<uint32_t>> words_;
  std::map<std::vector<uint32_t>, uint32_t> by_word_;
  size_t base_size_ = 0;
  size_t max_maps_ = size_t{1} << 16;
};

}  // namespace nimbus
