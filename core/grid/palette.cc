#include "core/grid/palette.h"

#include <algorithm>
#include <cmath>
#include <numbers>

namespace nimbus {

namespace {
constexpr double kBase[3] = {0.4, 0.6, 0.7};
constexpr double kPhase[3] = {0.5, 0.9, 1.3};
constexpr double kAmplitude = 0.25;
}  // namespace

Vec3 Palette::Eval(double t) const {
  if (!(t >= 0)) t = 0;  // also catches NaN
  if (t > 1) t = 1;
  if (stops_.empty()) {
    const double a = 2 * std::numbers::pi * t;
    return {kBase[0] + kAmplitude * std::sin(kPhase[0] + a),
            kBase[1] + kAmplitude * std::sin(kPhase[1] + a),
            kBase[2] + kAmplitude * std::sin(kPhase[2] + a)};
  }
  if (t <= stops_.front().position) return stops_.front().rgb;
  if (t >= stops_.back().position) return stops_.back().rgb;
  const auto hi = std::upper_bound(stops_.begin(), stops_.end(), t,
                                   [](double v, const PaletteStop& s) { return v < s.position; });
  const auto lo = hi - 1;
  const double span = hi->position - lo->position;
  const double u = span > 0 ? (t - lo->position) / span : 0;
  return lo->rgb + u * (hi->rgb - lo->rgb);
}

Vec3 Palette::MinColor() const {
  if (stops_.empty())
    return {kBase[0] - kAmplitude, kBase[1] - kAmplitude, kBase[2] - kAmplitude};
  Vec3 m = stops_[0].rgb;
  for (const auto& s : stops_)
    for (int a = 0; a < 3; ++a) m[a] = std::min(m[a], s.rgb[a]);
  return m;
}

Vec3 Palette::MaxColor() const {
  if (stops_.empty())
    return {kBase[0] + kAmplitude, kBase[1] + kAmplitude, kBase[2] + kAmplitude};
  Vec3 m = stops_[0].rgb;
  for (const auto& s : stops_)
    for (int a = 0; a < 3; ++a) m[a] = std::max(m[a], s.rgb[a]);
  return m;
}

}  // namespace nimbus
