// Small helpers shared by the IFS-matrix sources (not part of the API):
// message formatting and the affine view of a map.
#pragma once

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "core/chaos/point_map.h"

namespace nimbus::matrix_internal {

// A map without variations is affine even with a post: post o pre.
inline bool HasNoVariations(const PointMap& m) { return m.variations.empty(); }

inline Affine3 AffineOf(const PointMap& m) { return m.post ? *m.post * m.pre : m.pre; }

// absl here is built with its own string_view type, so std::string_view
// values go through std::string before reaching StrCat.
inline std::string Quoted(std::string_view s) {
  std::string out;
  out.reserve(s.size() + 2);
  out.push_back('\'');
  out.append(s);
  out.push_back('\'');
  return out;
}

inline std::string CellText(uint32_t i, uint32_t j) { return absl::StrCat("(", i, ", ", j, ")"); }

// Lists up to a dozen names for "unknown X" messages.
template <typename Range>
std::string NameList(const Range& names) {
  std::vector<std::string> shown;
  size_t total = 0;
  for (const auto& n : names) {
    if (shown.size() < 12) shown.emplace_back(n);
    ++total;
  }
  std::string out = absl::StrJoin(shown, ", ");
  if (total > shown.size()) absl::StrAppend(&out, ", ... (", total, " in all)");
  return total == 0 ? std::string("none") : out;
}

}  // namespace nimbus::matrix_internal
