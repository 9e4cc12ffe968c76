// @brief The plan of a set-IFS job: its set maps (with their condensation
// sources), probabilities, and either the random iteration or the book.
// Protobuf-free; made by the spec converter, run by the set-IFS runner.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "core/chaos/point_map.h"
#include "core/sets/set_maps.h"
#include "core/sets/set_source.h"

namespace nimbus {

/// @brief A checked SetMap.
struct SetMapPlan {
  SetMapKind kind = SetMapKind::kMedian;
  std::string field;
  /// Condensation set of median, rotated-median and constant maps.
  std::optional<SetSourcePlan> condensation;
  MedianOptions median;
  RotatedMedianOptions rotated;
  std::optional<PointMap> point;
};

/// @brief What a set-IFS job runs.
struct SetIfsPlan {
  std::vector<SetMapPlan> maps;
  /// Normalised, one per map.
  std::vector<double> probabilities;
  /// Book address letters, one per map.
  std::vector<std::string> labels;
  bool book = false;
  // Random iteration.
  uint64_t iterations = 0;
  uint64_t warmup = 16;
  // Book.
  int depth = 0;
  uint64_t pages = 0;
  uint64_t seed = 0;
  std::optional<SetSourcePlan> start;
  /// Memory the book may use for shared intermediate pages.
  uint64_t book_cache_bytes = uint64_t{256} << 20;
};

}  // namespace nimbus
