// @brief A list of point maps laid out for the batched flame kernels
// (flame_walk.h): flat tables, the terms in the order a walker sums them,
// and where each random term finds its pre-drawn numbers.
#pragma once

#include <cstdint>
#include <vector>

#include "core/base/cpu_dispatch.h"
#include "core/base/random.h"
#include "core/chaos/flame_walk.h"
#include "core/chaos/point_map.h"

namespace nimbus {

class FlameProgram {
 public:
  FlameProgram() = default;
  explicit FlameProgram(const std::vector<PointMap>& maps);
  // tables() points into the vectors, whose buffers survive a move only.
  FlameProgram(const FlameProgram&) = delete;
  FlameProgram& operator=(const FlameProgram&) = delete;
  FlameProgram(FlameProgram&&) = default;
  FlameProgram& operator=(FlameProgram&&) = default;

  const flame::MapTables& tables() const { return view_; }
  /// Columns of pre-drawn numbers a batch needs (the most any map takes).
  uint32_t draw_columns() const { return columns_; }
  /// Draws the numbers of one application of map `map`, in the order the
  /// scalar engine draws them, into draws[column * kSlots + slot].
  void Draw(uint32_t map, Rng& rng, double* draws, int slot) const;

 private:
  std::vector<double> pre_, post_, has_post_, has_terms_;
  std::vector<flame::Term> terms_;
  // Per map: the kinds of its random terms, in order.
  std::vector<std::vector<VariationKind>> random_;
  uint32_t columns_ = 0;
  flame::MapTables view_;
};

/// The kernel for a SIMD level (never above what the CPU has).
flame::ApplyMapsFn FlameKernel(SimdLevel level);

}  // namespace nimbus
