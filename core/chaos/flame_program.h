// @brief A job's maps laid out for the flame kernels (flame_walk.h): flat
// tables, each map's terms in the order a walker sums them, the alias table
// and the colour rule, and how many random words a step draws.
#pragma once

#include <cstdint>
#include <optional>
#include <vector>

#include "core/base/cpu_dispatch.h"
#include "core/chaos/flame_plot.h"
#include "core/chaos/flame_walk.h"
#include "core/chaos/point_map.h"

namespace nimbus {

class FlameProgram {
 public:
  FlameProgram() = default;
  /// `color_mode`: 0 none, 1 by map, 2 by address (flame::Program).
  FlameProgram(const std::vector<PointMap>& maps, const std::optional<PointMap>& final_map,
               const AliasTable& table, int color_mode, double blend);
  // program() points into the vectors, whose buffers survive a move only.
  FlameProgram(const FlameProgram&) = delete;
  FlameProgram& operator=(const FlameProgram&) = delete;
  FlameProgram(FlameProgram&&) = default;
  FlameProgram& operator=(FlameProgram&&) = default;

  const flame::Program& program() const { return view_; }

  /// Random words one application of `map` reads (formulas::VariationDraws
  /// summed over its terms).
  static uint32_t MapWords(const PointMap& map);
  /// Whether `map` keeps a flame planar: from any finite point it gives
  /// x and y that do not depend on z (no z in its x and y rows, whose
  /// constants are not -0, so adding a zero from z cannot flip a zero's
  /// sign), and z = +0 exactly (a zero z row with the constant +0, no
  /// post-affine, and only variations that return the pre-transformed z
  /// scaled or through sin, or add its square to x^2 + y^2: every kind
  /// but blur and noise). docs/chaos_game.md gives the argument.
  static bool Planar(const PointMap& map);

 private:
  struct Tables {
    std::vector<double> pre, post, color;
    std::vector<uint8_t> has_post, has_terms;
    std::vector<uint32_t> first_term, words;
    std::vector<flame::Term> terms;
    void Add(const PointMap& map);
    flame::MapTables View() const;
  };
  Tables maps_, final_;
  flame::Program view_;
};

/// The kernel for a SIMD level (never above what the CPU has).
flame::RoundFn FlameKernel(SimdLevel level);
/// The plot kernel for a SIMD level (never above what the CPU has); all
/// levels compute the same keys.
flame::PlotFn FlamePlotter(SimdLevel level);

}  // namespace nimbus
