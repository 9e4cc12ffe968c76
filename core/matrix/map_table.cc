#include "core/matrix/map_table.h"

#include <algorithm>
#include <string>
#include <utility>

#include "absl/strings/str_cat.h"
#include "core/matrix/matrix_text.h"

namespace nimbus {

using matrix_internal::AffineOf;
using matrix_internal::HasNoVariations;
using matrix_internal::NameList;
using matrix_internal::Quoted;

MapTable::MapTable(std::vector<PointMap> base_maps) : maps_(std::move(base_maps)) {
  base_size_ = maps_.size();
  words_.reserve(maps_.size());
  for (uint32_t i = 0; i < maps_.size(); ++i) {
    words_.push_back({i});
    by_word_.emplace(words_.back(), i);
  }
  max_maps_ = std::max(max_maps_, maps_.size());
}

absl::StatusOr<uint32_t> MapTable::Find(std::string_view name) const {
  for (uint32_t i = 0; i < maps_.size(); ++i)
    if (maps_[i].name == name) return i;
  std::vector<std::string_view> names;
  for (const PointMap& m : maps_) names.push_back(m.name);
  return absl::NotFoundError(
      absl::StrCat("unknown map ", Quoted(name), "; defined maps: ", NameList(names)));
}

absl::StatusOr<uint32_t> MapTable::Append(PointMap map, std::vector<uint32_t> word) {
  if (maps_.size() >= max_maps_)
    return absl::ResourceExhaustedError(absl::StrCat("the map table is full (", max_maps_,
                                                     " maps) while adding ", Quoted(map.name)));
  const uint32_t index = static_cast<uint32_t>(maps_.size());
  maps_.push_back(std::move(map));
  by_word_.emplace(word, index);
  words_.push_back(std::move(word));
  return index;
}

absl::StatusOr<uint32_t> MapTable::Identity() {
  if (auto it = by_word_.find({}); it != by_word_.end()) return it->second;
  PointMap id;
  id.name = "identity";
  return Append(std::move(id), {});
}

absl::StatusOr<uint32_t> MapTable::Compose(uint32_t f, uint32_t g) {
  if (f >= maps_.size() || g >= maps_.size())
    return absl::OutOfRangeError(
        absl::StrCat("map index ", std::max(f, g), " is outside the table of ", maps_.size()));
  // Identity is neutral: no new entry, and the identity never hides in a word.
  if (IsIdentity(f)) return g;
  if (IsIdentity(g)) return f;
  std::vector<uint32_t> word = words_[f];
  word.insert(word.end(), words_[g].begin(), words_[g].end());
  if (auto it = by_word_.find(word); it != by_word_.end()) return it->second;

  const PointMap& outer = maps_[f];
  const PointMap& inner = maps_[g];
  if (!HasNoVariations(outer))
    return absl::InvalidArgumentError(absl::StrCat(
        "cannot compose ", Quoted(outer.name), " after ", Quoted(inner.name), ": ",
        Quoted(outer.name),
        " has nonlinear variations, and only an affine map can be composed after another map"));
  PointMap out;
  if (HasNoVariations(inner)) {
    out.pre = AffineOf(outer) * AffineOf(inner);
  } else {
    // The outer affine folds into the inner map's post; its variations, which
    // depend on their own pre-affine, stay untouched.
    out = inner;
    out.post = AffineOf(outer) * (inner.post ? *inner.post : Affine3::Identity());
  }
  out.name = absl::StrCat(outer.name, ".", inner.name);
  // The point's colour follows the last map applied, the outer one.
  out.color = outer.color;
  return Append(std::move(out), std::move(word));
}

}  // namespace nimbus
