// Flame-style variations in 3D. docs/variations.md is the reference for every
// formula and for the conventions used here:
//  - planar variations use cylindrical coordinates (rho, theta, z) with
//    rho = sqrt(x^2 + y^2), theta = atan2(y, x); z passes through unchanged
//    (polar_doubling alone scales z, so that its |V| = |p| / sqrt 2 in 3D as well);
//  - the 3D ones use r = |p|;
//  - kEps guards the divisions that flam3 guards.
#include "core/chaos/variations.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <numbers>

namespace nimbus {
namespace {

// flam3's guard against division by zero, added where flam3 adds it.
constexpr double kEps = 1e-10;
constexpr double kPi = std::numbers::pi;
constexpr double kInvSqrt2 = 0.70710678118654752440;  // 1 / sqrt 2

constexpr int kNumVariations = static_cast<int>(VariationKind::kPolarDoubling) + 1;

// Indexed by the enum value; the static_assert below keeps it in step.
constexpr std::array<VariationInfo, kNumVariations> kInfo = {{
    // name, param_count, planar, random, reads_pre
    {"linear", 0, false, false, false},
    {"sinusoidal", 0, false, false, false},
    {"spherical", 0, false, false, false},
    {"swirl", 0, true, false, false},
    {"horseshoe", 0, true, false, false},
    {"polar", 0, true, false, false},
    {"handkerchief", 0, true, false, false},
    {"heart", 0, true, false, false},
    {"disc", 0, true, false, false},
    {"spiral", 0, true, false, false},
    {"hyperbolic", 0, true, false, false},
    {"diamond", 0, true, false, false},
    {"ex", 0, true, false, false},
    {"julia", 0, true, true, false},
    {"bent", 0, true, false, false},
    {"waves", 0, true, false, true},
    {"fisheye", 0, true, false, false},
    {"popcorn", 0, true, false, true},
    {"exponential", 0, true, false, false},
    {"power", 0, true, false, false},
    {"cylinder", 0, true, false, false},
    {"bubble", 0, false, false, false},
    {"blur", 0, false, true, false},
    {"noise", 0, false, true, false},
    {"polar_doubling", 0, true, false, false},
}};
static_assert(kInfo.back().name == "polar_doubling", "kInfo must follow the enum order");

// Planar radius and the cosine/sine of the planar angle. Ratios instead of
// atan2 + sincos because this runs in the chaos-game hot loop; at the axis
// the angle is taken as 0, matching atan2(0, 0). A NaN radius must stay NaN
// (so the walker is re-seeded), hence the test for zero, not for > 0.
struct PlanarAngle {
  double rho, cos_t, sin_t;
};
inline PlanarAngle Planar(Vec3 p) {
  const double rho = std::sqrt(p.x * p.x + p.y * p.y);
  if (rho == 0) return {0.0, 1.0, 0.0};
  return {rho, p.x / rho, p.y / rho};
}

// Uniform direction on the unit sphere from exactly two draws (no rejection
// loop, so the number of draws per call is fixed and easy to reproduce).
inline Vec3 RandomDirection(Rng& rng) {
  const double cz = 2.0 * rng.Uniform() - 1.0;  // uniform cos(polar angle)
  const double phi = 2.0 * kPi * rng.Uniform();
  const double sz = std::sqrt(std::max(0.0, 1.0 - cz * cz));
  return {sz * std::cos(phi), sz * std::sin(phi), cz};
}

}  // namespace

Vec3 EvaluateVariation(const VariationTerm& v, Vec3 p, const Affine3& pre, Rng& rng) {
  const double x = p.x, y = p.y, z = p.z;
  switch (v.kind) {
    case VariationKind::kLinear:
      return p;
    case VariationKind::kSinusoidal:
      return {std::sin(x), std::sin(y), std::sin(z)};
    case VariationKind::kSpherical: {
      const double inv = 1.0 / (Dot(p, p) + kEps);
      return inv * p;
    }
    case VariationKind::kSwirl: {
      const double r2 = x * x + y * y;
      const double s = std::sin(r2), c = std::cos(r2);
      return {x * s - y * c, x * c + y * s, z};
    }
    case VariationKind::kHorseshoe: {
      const double inv = 1.0 / (std::sqrt(x * x + y * y) + kEps);
      return {inv * (x - y) * (x + y), inv * 2.0 * x * y, z};
    }
    case VariationKind::kPolar: {
      const double rho = std::sqrt(x * x + y * y);
      return {std::atan2(y, x) / kPi, rho - 1.0, z};
    }
    case VariationKind::kHandkerchief: {
      const double rho = std::sqrt(x * x + y * y);
      const double t = std::atan2(y, x);
      return {rho * std::sin(t + rho), rho * std::cos(t - rho), z};
    }
    case VariationKind::kHeart: {
      const double rho = std::sqrt(x * x + y * y);
      const double a = std::atan2(y, x) * rho;
      return {rho * std::sin(a), -rho * std::cos(a), z};
    }
    case VariationKind::kDisc: {
      const double pr = kPi * std::sqrt(x * x + y * y);
      const double k = std::atan2(y, x) / kPi;
      return {k * std::sin(pr), k * std::cos(pr), z};
    }
    case VariationKind::kSpiral: {
      const PlanarAngle a = Planar(p);
      const double inv = 1.0 / (a.rho + kEps);
      return {inv * (a.cos_t + std::sin(a.rho)), inv * (a.sin_t - std::cos(a.rho)), z};
    }
    case VariationKind::kHyperbolic: {
      const PlanarAngle a = Planar(p);
      // rho * cos(theta) is x itself, also at the axis.
      return {a.sin_t / (a.rho + kEps), x, z};
    }
    case VariationKind::kDiamond: {
      const PlanarAngle a = Planar(p);
      return {a.sin_t * std::cos(a.rho), a.cos_t * std::sin(a.rho), z};
    }
    case VariationKind::kEx: {
      const double rho = std::sqrt(x * x + y * y);
      const double t = std::atan2(y, x);
      const double p0 = std::sin(t + rho), p1 = std::cos(t - rho);
      const double p03 = p0 * p0 * p0, p13 = p1 * p1 * p1;
      return {rho * (p03 + p13), rho * (p03 - p13), z};
    }
    case VariationKind::kJulia: {
      // Principal square root, then the other root half of the time, so the
      // attractor gets both branches of z -> sqrt(z).
      const double sr = std::sqrt(std::sqrt(x * x + y * y));
      double t = 0.5 * std::atan2(y, x);
      if (rng.Next() >> 63) t += kPi;
      return {sr * std::cos(t), sr * std::sin(t), z};
    }
    case VariationKind::kBent: {
      return {x < 0 ? 2.0 * x : x, y < 0 ? 0.5 * y : y, z};
    }
    case VariationKind::kWaves: {
      // Flame notation x' = a x + b y + c, y' = d x + e y + f.
      const double b = pre.m[0][1], c = pre.m[0][3];
      const double e = pre.m[1][1], f = pre.m[1][3];
      return {x + b * std::sin(y / (c * c + kEps)), y + e * std::sin(x / (f * f + kEps)), z};
    }
    case VariationKind::kFisheye: {
      const double k = 2.0 / (std::sqrt(x * x + y * y) + 1.0);
      return {k * y, k * x, z};  // the swap is part of the classic form
    }
    case VariationKind::kPopcorn: {
      const double c = pre.m[0][3], f = pre.m[1][3];
      return {x + c * std::sin(std::tan(3.0 * y)), y + f * std::sin(std::tan(3.0 * x)), z};
    }
    case VariationKind::kExponential: {
      const double k = std::exp(x - 1.0);
      return {k * std::cos(kPi * y), k * std::sin(kPi * y), z};
    }
    case VariationKind::kPower: {
      const PlanarAngle a = Planar(p);
      const double k = std::pow(a.rho, a.sin_t);
      return {k * a.cos_t, k * a.sin_t, z};
    }
    case VariationKind::kCylinder:
      return {std::sin(x), y, z};
    case VariationKind::kBubble: {
      const double k = 4.0 / (Dot(p, p) + 4.0);
      return k * p;
    }
    case VariationKind::kBlur: {
      const Vec3 d = RandomDirection(rng);
      return std::cbrt(rng.Uniform()) * d;  // cube root: uniform in volume
    }
    case VariationKind::kNoise: {
      const Vec3 d = RandomDirection(rng);
      const double s = rng.Uniform();
      return {s * x * d.x, s * y * d.y, s * z * d.z};
    }
    case VariationKind::kPolarDoubling: {
      // (rho, theta) -> (rho / sqrt 2, 2 theta) via the double-angle identities.
      const PlanarAngle a = Planar(p);
      const double k = kInvSqrt2 * a.rho;
      return {k * (a.cos_t * a.cos_t - a.sin_t * a.sin_t), k * 2.0 * a.cos_t * a.sin_t,
              kInvSqrt2 * z};
    }
  }
  return p;  // unreachable for valid kinds; keeps out-of-range values harmless
}

const VariationInfo& GetVariationInfo(VariationKind kind) {
  const auto i = static_cast<size_t>(kind);
  return kInfo[i < kInfo.size() ? i : 0];
}

std::string_view VariationName(VariationKind kind) { return GetVariationInfo(kind).name; }

std::optional<VariationKind> VariationFromName(std::string_view name) {
  for (int i = 0; i < kNumVariations; ++i)
    if (kInfo[i].name == name) return static_cast<VariationKind>(i);
  return std::nullopt;
}

const std::vector<VariationKind>& AllVariations() {
  static const std::vector<VariationKind> all = [] {
    std::vector<VariationKind> kinds;
    kinds.reserve(kNumVariations);
    for (int i = 0; i < kNumVariations; ++i) kinds.push_back(static_cast<VariationKind>(i));
    return kinds;
  }();
  return all;
}

}  // namespace nimbus
