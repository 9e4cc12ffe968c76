// @brief The variation formulas of docs/variations.md written once, as
// templates over the number type: `double` for the engine's scalar code
// (variations.cc) and SIMD vectors for the batched flame kernels
// (flame_walk_*.cc), so every kernel evaluates the same expressions in the
// same order and only the elementary functions differ between them.
//
// A type T used here needs, declared before this header is included (plain
// and vector types have no namespace for argument-dependent lookup to find
// them in): T +-*/ T and T with double (GCC vector extensions give that for
// __m256d and __m512d), Sqrt, Sin, Cos, Tan, Atan2, Exp, Pow, Cbrt, and the
// mask operations IsNegative, IsZero, IsPositive and Select(mask, a, b). The
// overloads for double are below. Everything sits in an unnamed namespace:
// a SIMD translation unit compiles this header with wider instructions,
// and an inline function with external linkage compiled there could be the
// copy the linker keeps for the rest of the program.
#pragma once

#include <cmath>
#include <numbers>

#include "core/chaos/variation_kind.h"

namespace nimbus::formulas {
namespace {

inline double Sqrt(double a) { return std::sqrt(a); }
inline double Sin(double a) { return std::sin(a); }
inline double Cos(double a) { return std::cos(a); }
// Both at once where the vector library has one call for the two.
inline void SinCos(double a, double* s, double* c) { *s = std::sin(a), *c = std::cos(a); }
inline double Tan(double a) { return std::tan(a); }
inline double Atan2(double y, double x) { return std::atan2(y, x); }
inline double Exp(double a) { return std::exp(a); }
inline double Pow(double a, double b) { return std::pow(a, b); }
inline double Cbrt(double a) { return std::cbrt(a); }
inline bool IsNegative(double a) { return a < 0; }
inline bool IsZero(double a) { return a == 0; }
inline bool IsPositive(double a) { return 0 < a; }
inline double Select(bool m, double a, double b) { return m ? a : b; }
inline bool AllZero(double a) { return a == 0; }

// flam3's guard against division by zero, added where flam3 adds it.
constexpr double kEps = 1e-10;
constexpr double kPi = std::numbers::pi;
constexpr double kInvSqrt2 = 0.70710678118654752440;  // 1 / sqrt 2

// sin a, without the call where every lane is +-0 (z of a 2D flame):
// sin(+-0) = +-0 exactly in the C library and in SLEEF, so no bit changes.
template <class T>
inline T SinOrZero(T a) {
  return AllZero(a) ? a : Sin(a);
}

template <class T>
struct P3 {
  T x, y, z;
};

template <class T>
inline P3<T> Scaled(T s, const P3<T>& p) {
  return {s * p.x, s * p.y, s * p.z};
}

// Planar radius and the sine and cosine of flam3's planar angle, which is
// measured from +y towards +x: sin = x / rho, cos = y / rho. Ratios instead
// of atan2 + sincos; at the axis the angle is 0 (atan2(0, 0)). A NaN radius
// stays NaN so the walker is re-seeded, hence the test for zero.
template <class T>
struct PlanarAngle {
  T rho, sin_t, cos_t;
};
template <class T>
inline PlanarAngle<T> Planar(const P3<T>& p) {
  const T rho = Sqrt(p.x * p.x + p.y * p.y);
  const auto axis = IsZero(rho);
  return {rho, Select(axis, 0.0 * rho, p.x / rho), Select(axis, 0.0 * rho + 1.0, p.y / rho)};
}

// Uniform direction on the unit sphere from exactly two draws (no rejection
// loop, so the number of draws per call is fixed and easy to reproduce).
template <class T, class R>
inline P3<T> RandomDirection(R& rng) {
  const T cz = 2.0 * rng.Uniform() - 1.0;  // uniform cos(polar angle)
  const T phi = 2.0 * kPi * rng.Uniform();
  const T c2 = 1.0 - cz * cz;
  const T sz = Sqrt(Select(IsPositive(c2), c2, 0.0 * c2));
  T s, c;
  SinCos(phi, &s, &c);
  return {sz * c, sz * s, cz};
}

/// Variation `kind` (unweighted) at the pre-transformed point `p`. `pre` is
/// the map's pre-affine as 12 row-major coefficients, read by the dependent
/// variations. `rng` supplies Uniform() (a T in [0, 1)) and Bit() (a mask:
/// the top bit of one raw draw), in the order docs/variations.md gives.
template <class T, class R>
[[gnu::always_inline]] inline P3<T> Variation(VariationKind kind, const P3<T>& p, const double* pre,
                                             R& rng) {
  const T x = p.x, y = p.y, z = p.z;
  switch (kind) {
    case VariationKind::kLinear:
      return p;
    case VariationKind::kSinusoidal:
      return {Sin(x), Sin(y), SinOrZero(z)};
    case VariationKind::kSpherical:
      return Scaled<T>(1.0 / ((x * x + y * y + z * z) + kEps), p);
    case VariationKind::kSwirl: {
      const T r2 = x * x + y * y;
      T s, c;
      SinCos(r2, &s, &c);
      return {x * s - y * c, x * c + y * s, z};
    }
    case VariationKind::kHorseshoe: {
      const T inv = 1.0 / (Sqrt(x * x + y * y) + kEps);
      return {inv * (x - y) * (x + y), inv * 2.0 * x * y, z};
    }
    case VariationKind::kPolar:
      return {Atan2(x, y) / kPi, Sqrt(x * x + y * y) - 1.0, z};
    case VariationKind::kHandkerchief: {
      const T rho = Sqrt(x * x + y * y);
      const T t = Atan2(x, y);
      return {rho * Sin(t + rho), rho * Cos(t - rho), z};
    }
    case VariationKind::kHeart: {
      const T rho = Sqrt(x * x + y * y);
      const T a = Atan2(x, y) * rho;
      return {rho * Sin(a), -rho * Cos(a), z};
    }
    case VariationKind::kDisc: {
      const T pr = kPi * Sqrt(x * x + y * y);
      const T k = Atan2(x, y) / kPi;
      return {k * Sin(pr), k * Cos(pr), z};
    }
    case VariationKind::kSpiral: {
      const PlanarAngle<T> a = Planar(p);
      const T inv = 1.0 / (a.rho + kEps);
      return {inv * (a.cos_t + Sin(a.rho)), inv * (a.sin_t - Cos(a.rho)), z};
    }
    case VariationKind::kHyperbolic: {
      const PlanarAngle<T> a = Planar(p);
      const T r = a.rho + kEps;
      return {a.sin_t / r, a.cos_t * r, z};
    }
    case VariationKind::kDiamond: {
      const PlanarAngle<T> a = Planar(p);
      return {a.sin_t * Cos(a.rho), a.cos_t * Sin(a.rho), z};
    }
    case VariationKind::kEx: {
      const T rho = Sqrt(x * x + y * y);
      const T t = Atan2(x, y);
      const T p0 = Sin(t + rho), p1 = Cos(t - rho);
      const T p03 = p0 * p0 * p0, p13 = p1 * p1 * p1;
      return {rho * (p03 + p13), rho * (p03 - p13), z};
    }
    case VariationKind::kJulia: {
      // The principal square root of u = y + i x (whose argument is
      // flam3's angle) by the half-angle identities, without atan2, sin or
      // cos: |re| = sqrt((rho + y) / 2), |im| = sqrt((rho - y) / 2), the
      // smaller one as |x| / (2 x the larger) to avoid cancellation, im
      // with the sign of x. Then its negative half of the time, so the
      // attractor gets both branches.
      const T rho = Sqrt(x * x + y * y);
      const T ay = Select(IsNegative(y), 0.0 - y, y), ax = Select(IsNegative(x), 0.0 - x, x);
      const T big = Sqrt(0.5 * (rho + ay));
      const T small = Select(IsZero(big), 0.0 * big, ax / (2.0 * big));
      const auto lower = IsNegative(y);
      const T re = Select(lower, small, big);
      const T mag = Select(lower, big, small);
      const T im = Select(IsNegative(x), 0.0 - mag, mag);
      const auto other = rng.Bit();
      return {Select(other, 0.0 - re, re), Select(other, 0.0 - im, im), z};
    }
    case VariationKind::kBent:
      return {Select(IsNegative(x), 2.0 * x, x), Select(IsNegative(y), 0.5 * y, y), z};
    case VariationKind::kWaves: {
      // Flame notation x' = a x + b y + c, y' = d x + e y + f.
      const double b = pre[1], c = pre[3], e = pre[5], f = pre[7];
      return {x + b * Sin(y / (c * c + kEps)), y + e * Sin(x / (f * f + kEps)), z};
    }
    case VariationKind::kFisheye: {
      const T k = 2.0 / (Sqrt(x * x + y * y) + 1.0);
      return {k * y, k * x, z};  // the swap is part of the classic form
    }
    case VariationKind::kPopcorn: {
      const double c = pre[3], f = pre[7];
      return {x + c * Sin(Tan(3.0 * y)), y + f * Sin(Tan(3.0 * x)), z};
    }
    case VariationKind::kExponential: {
      const T k = Exp(x - 1.0);
      T s, c;
      SinCos(kPi * y, &s, &c);
      return {k * c, k * s, z};
    }
    case VariationKind::kPower: {
      const PlanarAngle<T> a = Planar(p);
      const T k = Pow(a.rho, a.sin_t);
      return {k * a.cos_t, k * a.sin_t, z};
    }
    case VariationKind::kCylinder:
      return {Sin(x), y, z};
    case VariationKind::kBubble:
      return Scaled<T>(4.0 / ((x * x + y * y + z * z) + 4.0), p);
    case VariationKind::kBlur: {
      const P3<T> d = RandomDirection<T>(rng);
      return Scaled<T>(Cbrt(rng.Uniform()), d);  // cube root: uniform in volume
    }
    case VariationKind::kNoise: {
      const P3<T> d = RandomDirection<T>(rng);
      const T s = rng.Uniform();
      return {s * x * d.x, s * y * d.y, s * z * d.z};
    }
    case VariationKind::kPolarDoubling: {
      // (rho, theta) -> (rho / sqrt 2, 2 theta) with theta from +x (the
      // reference description's own map, not a flam3 one), via the
      // double-angle identities; the angle is 0 at the axis.
      const T rho = Sqrt(x * x + y * y);
      const auto axis = IsZero(rho);
      const T c = Select(axis, 0.0 * rho + 1.0, x / rho), s = Select(axis, 0.0 * rho, y / rho);
      const T k = kInvSqrt2 * rho;
      return {k * (c * c - s * s), k * 2.0 * c * s, kInvSqrt2 * z};
    }
  }
  return p;  // unreachable for valid kinds; keeps out-of-range values harmless
}

/// Random draws a variation takes per evaluation: raw words for Bit(),
/// uniforms for Uniform(); callers that pre-draw fill them in this order.
inline int VariationDraws(VariationKind kind) {
  switch (kind) {
    case VariationKind::kJulia:
      return 1;
    case VariationKind::kBlur:
    case VariationKind::kNoise:
      return 3;
    default:
      return 0;
  }
}

}  // namespace
}  // namespace nimbus::formulas
