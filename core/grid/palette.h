// Colour palettes: a scalar colour coordinate in [0, 1] to an RGB colour.
#pragma once

#include <array>
#include <cstddef>
#include <vector>

#include "core/base/geometry.h"

namespace nimbus {

/// One stop of a gradient palette.
struct PaletteStop {
  double position = 0;  // in [0, 1], stops sorted by position
  Vec3 rgb;             // linear RGB
};

/// @brief Maps a colour coordinate t in [0, 1] to RGB. The default is the
/// reference description's sine palette (docs/algorithms.md#the-look-of-the-attractor) with a = 2*pi*t, so the
/// palette runs through one full period over the coordinate's range:
///   r = 0.4 + 0.25 sin(0.5 + a), g = 0.6 + 0.25 sin(0.9 + a),
///   b = 0.7 + 0.25 sin(1.3 + a).
/// With stops it is the piecewise-linear gradient through them, clamped to
/// the first and last stop outside their positions.
class Palette {
 public:
  /// The sine palette.
  Palette() = default;
  /// A gradient; `stops` must be non-empty and sorted by position.
  explicit Palette(std::vector<PaletteStop> stops) : stops_(std::move(stops)) {}

  Vec3 Eval(double t) const;
  /// out[k] = Eval(t[k]) rounded to float, channel by channel, for k < n:
  /// bit for bit what the per-value call gives, faster for the sine
  /// palette (its sines computed eight at a time; see the .cc).
  void EvalFloats(const double* t, size_t n, std::array<float, 3>* out) const;
  /// out[k] near Eval(t[k]) for k < n: each channel within 2^-50 of it (the
  /// sine palette's sines eight at a time), exactly it with stops. For
  /// callers that check their own rounding and fall back to Eval.
  void EvalNear(const double* t, size_t n, Vec3* out) const;
  bool is_sine() const { return stops_.empty(); }
  /// Per-channel bounds of every colour Eval can return.
  Vec3 MinColor() const;
  Vec3 MaxColor() const;

 private:
  std::vector<PaletteStop> stops_;
};

namespace palette_internal {
/// Whether every double within `margin` of y rounds to the float y rounds
/// to; ties, infinities and values that round to zero answer false (zero
/// itself only with no margin). The guard of callers that compute near
/// Eval's values and fall back to it.
bool RoundsAlike(double y, double margin);
/// RoundsAlike(v, 2^-50): EvalFloats' guard for its batched sines.
bool RoundsSafely(double v);
}  // namespace palette_internal

}  // namespace nimbus
