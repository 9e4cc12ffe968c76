#include "core/grid/palette.h"

#include <algorithm>
#include <bit>
#include <cstdint>
#include <cmath>
#include <numbers>

#include "core/grid/sine_batch.h"

namespace nimbus {

namespace {
constexpr double kBase[3] = {0.4, 0.6, 0.7};
constexpr double kPhase[3] = {0.5, 0.9, 1.3};
constexpr double kAmplitude = 0.25;

// Channel c of the sine palette from its sine: one expression for the
// per-value and the batched path, whose floats must agree bit for bit.
double SineChannel(int c, double sine) { return kBase[c] + kAmplitude * sine; }

double Clamped(double t) {
  if (!(t >= 0)) return 0;  // also catches NaN
  return t > 1 ? 1 : t;
}

}  // namespace

namespace palette_internal {
bool RoundsAlike(double y, double margin) {
  if (y == 0 && margin == 0) return true;
  const float f = float(y);
  if (!std::isfinite(f) || f == 0) return false;
  // The neighbouring floats by their bits: nextafter's library calls were
  // half the guard's cost in EvalFloats.
  const double a = std::fabs(y), fa = std::fabs(double(f));
  const uint32_t bits = std::bit_cast<uint32_t>(float(fa));
  const double lo = (fa + double(std::bit_cast<float>(bits - 1))) / 2;
  const double hi = (fa + double(std::bit_cast<float>(bits + 1))) / 2;
  return a - lo > margin && hi - a > margin;
}

bool RoundsSafely(double v) { return RoundsAlike(v, 0x1.0p-50); }
}  // namespace palette_internal

// The sine palette in batches (EvalNear). A vector sine (SLEEF, within 1
// ulp) and the C library's (within 1 ulp) differ by at most 2 ulp, 2^-52
// for |s| <= 1; through 0.25 s and the base's add, with each operation's
// rounding, the channel's double differs by less than 2^-51. So where that
// double lies farther than 2^-50 from its float's rounding boundaries (all
// but about one value in four million), the float is the one Eval's value
// rounds to; elsewhere the channel is Eval's.
void Palette::EvalFloats(const double* t, size_t n, std::array<float, 3>* out) const {
  if (!stops_.empty()) {
    for (size_t k = 0; k < n; ++k) {
      const Vec3 c = Eval(t[k]);
      out[k] = {float(c.x), float(c.y), float(c.z)};
    }
    return;
  }
  constexpr size_t kBatch = 256;
  Vec3 near[kBatch];
  for (size_t begin = 0; begin < n; begin += kBatch) {
    const size_t m = std::min(kBatch, n - begin);
    EvalNear(t + begin, m, near);
    for (size_t k = 0; k < m; ++k)
      for (int c = 0; c < 3; ++c) {
        double v = near[k][c];
        if (!palette_internal::RoundsSafely(v)) [[unlikely]]
          v = Eval(t[begin + k])[c];
        out[begin + k][size_t(c)] = float(v);
      }
  }
}

void Palette::EvalNear(const double* t, size_t n, Vec3* out) const {
  if (!stops_.empty()) {
    for (size_t k = 0; k < n; ++k) out[k] = Eval(t[k]);
    return;
  }
  // Each channel within 2^-51 of Eval's (see EvalFloats).
  constexpr size_t kBatch = 256;
  double x[3 * kBatch], s[3 * kBatch];
  for (size_t begin = 0; begin < n; begin += kBatch) {
    const size_t m = std::min(kBatch, n - begin);
    for (size_t k = 0; k < m; ++k) {
      const double a = 2 * std::numbers::pi * Clamped(t[begin + k]);
      for (int c = 0; c < 3; ++c) x[3 * k + size_t(c)] = kPhase[c] + a;
    }
    SinMany(x, s, 3 * m);
    for (size_t k = 0; k < m; ++k)
      out[begin + k] = {SineChannel(0, s[3 * k]), SineChannel(1, s[3 * k + 1]),
                        SineChannel(2, s[3 * k + 2])};
  }
}

Vec3 Palette::Eval(double t) const {
  t = Clamped(t);
  if (stops_.empty()) {
    const double a = 2 * std::numbers::pi * t;
    return {SineChannel(0, std::sin(kPhase[0] + a)), SineChannel(1, std::sin(kPhase[1] + a)),
            SineChannel(2, std::sin(kPhase[2] + a))};
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
