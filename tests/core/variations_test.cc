#include "core/chaos/variations.h"

#include <gtest/gtest.h>

#include "core/chaos/chaos_game.h"

#include <algorithm>
#include <cmath>
#include <complex>
#include <functional>
#include <limits>
#include <numbers>
#include <optional>
#include <string>
#include <vector>

namespace nimbus {
namespace {

using Complex = std::complex<double>;
constexpr double kPi = std::numbers::pi;
constexpr double kEps = 1e-10;  // the guard documented in docs/variations.md

// Points in every octant, on the axes, near the origin and a little further out.
const std::vector<Vec3>& SamplePoints() {
  static const std::vector<Vec3> points = {
      {0.3, -0.7, 0.2},    {-1.2, 0.4, -0.9}, {2.5, 1.5, 0.5},    {-0.05, -0.02, 1.3},
      {0.9, 0.0, -0.4},    {-2.0, 0.0, 0.1},  {0.0, 1.7, 0.0},    {0.0, -0.6, -2.2},
      {1e-3, 2e-3, -3e-3}, {-0.8, -1.1, 0.6}, {1.9, -0.35, -1.4}, {-0.45, 2.1, 0.75},
  };
  return points;
}

// A pre-affine with distinct coefficients so that a mix-up shows. In flame
// notation: b = 0.3, c = 0.25, e = 0.7, f = -0.4.
Affine3 TestPre() {
  Affine3 a;
  a.m = {{{0.8, 0.3, 0.1, 0.25}, {-0.2, 0.7, 0.05, -0.4}, {0.1, 0.2, 0.9, 0.3}}};
  return a;
}

VariationTerm Term(VariationKind kind) { return VariationTerm{kind, 1.0, {}}; }

Complex Xy(Vec3 p) { return {p.x, p.y}; }
// flam3's planar angle, measured from +y towards +x (docs/variations.md).
double FlameAngle(Vec3 p) { return std::atan2(p.x, p.y); }
Vec3 FromXy(Complex w, double z) { return {w.real(), w.imag(), z}; }

// Relative to the size of the expected vector: near-zero components of a
// large vector carry the vector's rounding, not their own.
void ExpectClose(Vec3 got, Vec3 want, Vec3 at, const std::string& what) {
  const double tol = 1e-12 * std::max(Length(want), 1e-300);
  const std::string where = what + " at (" + std::to_string(at.x) + ", " + std::to_string(at.y) +
                            ", " + std::to_string(at.z) + ")";
  EXPECT_NEAR(got.x, want.x, tol) << where << " x";
  EXPECT_NEAR(got.y, want.y, tol) << where << " y";
  EXPECT_NEAR(got.z, want.z, tol) << where << " z";
}

// Checks a deterministic variation against `formula` at every sample point.
void ExpectFormula(VariationKind kind, const std::function<Vec3(Vec3)>& formula,
                   const Affine3& pre = TestPre()) {
  Rng rng(7, 0);
  for (Vec3 p : SamplePoints())
    ExpectClose(EvaluateVariation(Term(kind), p, pre, rng), formula(p), p,
                std::string(VariationName(kind)));
}

TEST(Variations, Linear) {
  ExpectFormula(VariationKind::kLinear, [](Vec3 p) { return p; });
}

TEST(Variations, Sinusoidal) {
  ExpectFormula(VariationKind::kSinusoidal, [](Vec3 p) {
    return Vec3{std::sin(p.x), std::sin(p.y), std::sin(p.z)};
  });
}

TEST(Variations, Spherical) {
  ExpectFormula(VariationKind::kSpherical, [](Vec3 p) {
    const double r2 = p.x * p.x + p.y * p.y + p.z * p.z;
    return Vec3{p.x / (r2 + kEps), p.y / (r2 + kEps), p.z / (r2 + kEps)};
  });
}

TEST(Variations, Swirl) {
  // x sin(rho^2) - y cos(rho^2) + i (x cos(rho^2) + y sin(rho^2)) = w * i * e^{-i rho^2}.
  ExpectFormula(VariationKind::kSwirl, [](Vec3 p) {
    const Complex w = Xy(p);
    return FromXy(w * Complex(0, 1) * std::exp(Complex(0, -std::norm(w))), p.z);
  });
}

TEST(Variations, Horseshoe) {
  ExpectFormula(VariationKind::kHorseshoe, [](Vec3 p) {
    const Complex w = Xy(p);
    return FromXy(w * w / (std::abs(w) + kEps), p.z);
  });
}

TEST(Variations, Polar) {
  ExpectFormula(VariationKind::kPolar, [](Vec3 p) {
    return Vec3{FlameAngle(p) / kPi, std::abs(Xy(p)) - 1.0, p.z};
  });
}

TEST(Variations, Handkerchief) {
  ExpectFormula(VariationKind::kHandkerchief, [](Vec3 p) {
    const double rho = std::abs(Xy(p)), t = FlameAngle(p);
    return Vec3{rho * std::sin(t + rho), rho * std::cos(t - rho), p.z};
  });
}

TEST(Variations, Heart) {
  ExpectFormula(VariationKind::kHeart, [](Vec3 p) {
    const double rho = std::abs(Xy(p)), t = FlameAngle(p);
    return Vec3{rho * std::sin(t * rho), -rho * std::cos(t * rho), p.z};
  });
}

TEST(Variations, Disc) {
  ExpectFormula(VariationKind::kDisc, [](Vec3 p) {
    const double rho = std::abs(Xy(p)), t = FlameAngle(p);
    return Vec3{t / kPi * std::sin(kPi * rho), t / kPi * std::cos(kPi * rho), p.z};
  });
}

TEST(Variations, Spiral) {
  ExpectFormula(VariationKind::kSpiral, [](Vec3 p) {
    const double rho = std::abs(Xy(p)), t = FlameAngle(p);
    return Vec3{(std::cos(t) + std::sin(rho)) / (rho + kEps),
                (std::sin(t) - std::cos(rho)) / (rho + kEps), p.z};
  });
}

TEST(Variations, Hyperbolic) {
  ExpectFormula(VariationKind::kHyperbolic, [](Vec3 p) {
    const double rho = std::abs(Xy(p)), t = FlameAngle(p);
    return Vec3{std::sin(t) / (rho + kEps), (rho + kEps) * std::cos(t), p.z};
  });
}

TEST(Variations, Diamond) {
  ExpectFormula(VariationKind::kDiamond, [](Vec3 p) {
    const double rho = std::abs(Xy(p)), t = FlameAngle(p);
    return Vec3{std::sin(t) * std::cos(rho), std::cos(t) * std::sin(rho), p.z};
  });
}

TEST(Variations, Ex) {
  ExpectFormula(VariationKind::kEx, [](Vec3 p) {
    const double rho = std::abs(Xy(p)), t = FlameAngle(p);
    const double a = std::pow(std::sin(t + rho), 3), b = std::pow(std::cos(t - rho), 3);
    return Vec3{rho * (a + b), rho * (a - b), p.z};
  });
}

TEST(Variations, Bent) {
  ExpectFormula(VariationKind::kBent, [](Vec3 p) {
    if (p.x >= 0 && p.y >= 0) return p;
    if (p.x < 0 && p.y >= 0) return Vec3{2 * p.x, p.y, p.z};
    if (p.x >= 0 && p.y < 0) return Vec3{p.x, p.y / 2, p.z};
    return Vec3{2 * p.x, p.y / 2, p.z};
  });
}

TEST(Variations, WavesReadsPreCoefficients) {
  ExpectFormula(VariationKind::kWaves, [](Vec3 p) {
    return Vec3{p.x + 0.3 * std::sin(p.y / (0.25 * 0.25 + kEps)),
                p.y + 0.7 * std::sin(p.x / (0.4 * 0.4 + kEps)), p.z};
  });
}

TEST(Variations, Fisheye) {
  ExpectFormula(VariationKind::kFisheye, [](Vec3 p) {
    const double k = 2.0 / (std::hypot(p.x, p.y) + 1.0);
    return Vec3{k * p.y, k * p.x, p.z};
  });
}

TEST(Variations, PopcornReadsPreTranslation) {
  ExpectFormula(VariationKind::kPopcorn, [](Vec3 p) {
    return Vec3{p.x + 0.25 * std::sin(std::tan(3 * p.y)), p.y - 0.4 * std::sin(std::tan(3 * p.x)),
                p.z};
  });
}

TEST(Variations, Exponential) {
  ExpectFormula(VariationKind::kExponential,
                [](Vec3 p) { return FromXy(std::exp(Complex(p.x - 1.0, kPi * p.y)), p.z); });
}

TEST(Variations, Power) {
  ExpectFormula(VariationKind::kPower, [](Vec3 p) {
    const double rho = std::abs(Xy(p)), t = FlameAngle(p);
    return FromXy(std::polar(std::pow(rho, std::sin(t)), t), p.z);
  });
}

TEST(Variations, Cylinder) {
  ExpectFormula(VariationKind::kCylinder, [](Vec3 p) { return Vec3{std::sin(p.x), p.y, p.z}; });
}

TEST(Variations, Bubble) {
  ExpectFormula(VariationKind::kBubble, [](Vec3 p) {
    const double k = 4.0 / (p.x * p.x + p.y * p.y + p.z * p.z + 4.0);
    return Vec3{k * p.x, k * p.y, k * p.z};
  });
}

TEST(Variations, PolarDoubling) {
  ExpectFormula(VariationKind::kPolarDoubling, [](Vec3 p) {
    const Complex w = Xy(p);
    return FromXy(std::polar(std::abs(w) / std::sqrt(2.0), 2 * std::arg(w)), p.z / std::sqrt(2.0));
  });
}

TEST(Variations, PolarDoublingContractsBySqrt2In3D) {
  Rng rng(1, 0);
  for (Vec3 p : SamplePoints()) {
    const Vec3 q = EvaluateVariation(Term(VariationKind::kPolarDoubling), p, {}, rng);
    EXPECT_NEAR(Dot(q, q), Dot(p, p) / 2, 1e-12 * Dot(p, p));
  }
}

TEST(Variations, JuliaMatchesEitherSquareRootFromSameDraw) {
  Rng rng(42, 3), twin(42, 3);
  int flipped = 0;
  for (int round = 0; round < 20; ++round) {
    for (Vec3 p : SamplePoints()) {
      const Vec3 got = EvaluateVariation(Term(VariationKind::kJulia), p, TestPre(), rng);
      // A square root of rho e^{i t} with flam3's angle t.
      Complex want = std::polar(std::sqrt(std::abs(Xy(p))), 0.5 * FlameAngle(p));
      if (twin.Next() >> 63) {
        want = -want;
        ++flipped;
      }
      ExpectClose(got, FromXy(want, p.z), p, "julia");
    }
  }
  // Both branches occur.
  const int total = 20 * static_cast<int>(SamplePoints().size());
  EXPECT_GT(flipped, total / 4);
  EXPECT_LT(flipped, 3 * total / 4);
}

// The documented draw order: cos(polar angle), azimuth, then the radius or scale.
Vec3 TwinDirection(Rng& twin) {
  const double cz = twin.Uniform(-1.0, 1.0);
  const double phi = twin.Uniform(0.0, 2 * kPi);
  const double sz = std::sqrt(1 - cz * cz);
  return {sz * std::cos(phi), sz * std::sin(phi), cz};
}

TEST(Variations, BlurReproducesDraws) {
  Rng rng(5, 11), twin(5, 11);
  for (int round = 0; round < 10; ++round) {
    for (Vec3 p : SamplePoints()) {
      const Vec3 got = EvaluateVariation(Term(VariationKind::kBlur), p, TestPre(), rng);
      const Vec3 d = TwinDirection(twin);
      const double radius = std::pow(twin.Uniform(), 1.0 / 3.0);
      ExpectClose(got, radius * d, p, "blur");
    }
  }
}

TEST(Variations, BlurIsUniformInUnitBall) {
  Rng rng(9, 0);
  const int n = 200000;
  int inner = 0;
  Vec3 mean;
  for (int i = 0; i < n; ++i) {
    const Vec3 q = EvaluateVariation(Term(VariationKind::kBlur), {5, -3, 2}, {}, rng);
    const double r = Length(q);
    ASSERT_LT(r, 1.0 + 1e-15);
    if (r < 0.5) ++inner;
    mean = mean + q;
  }
  // A ball of half the radius holds 1/8 of the volume.
  EXPECT_NEAR(inner / double(n), 0.125, 0.004);
  mean = (1.0 / n) * mean;
  EXPECT_LT(Length(mean), 0.01);
}

TEST(Variations, NoiseReproducesDraws) {
  Rng rng(8, 2), twin(8, 2);
  for (int round = 0; round < 10; ++round) {
    for (Vec3 p : SamplePoints()) {
      const Vec3 got = EvaluateVariation(Term(VariationKind::kNoise), p, TestPre(), rng);
      const Vec3 d = TwinDirection(twin);
      const double s = twin.Uniform();
      ExpectClose(got, Vec3{s * p.x * d.x, s * p.y * d.y, s * p.z * d.z}, p, "noise");
    }
  }
}

TEST(Variations, NoiseIsBoundedPerAxis) {
  Rng rng(3, 1);
  for (int round = 0; round < 2000; ++round) {
    for (Vec3 p : SamplePoints()) {
      const Vec3 q = EvaluateVariation(Term(VariationKind::kNoise), p, {}, rng);
      for (int i = 0; i < 3; ++i) ASSERT_LE(std::abs(q[i]), std::abs(p[i]));
      ASSERT_LE(Length(q), Length(p));
    }
  }
}

TEST(Variations, WeightIsNotApplied) {
  // The caller multiplies by the weight (point_map.h), so it must not be applied twice.
  for (VariationKind kind : AllVariations()) {
    Rng a(4, 4), b(4, 4);
    VariationTerm heavy = Term(kind);
    heavy.weight = 3.5;
    const Vec3 p{0.4, -0.3, 0.8};
    const Vec3 x = EvaluateVariation(Term(kind), p, TestPre(), a);
    const Vec3 y = EvaluateVariation(heavy, p, TestPre(), b);
    EXPECT_EQ(x, y) << VariationName(kind);
  }
}

TEST(Variations, DegenerateInputsStayFinite) {
  // With the epsilon guards every variation is finite at the origin, on the
  // z axis, and with pre coefficients of zero (identity pre: c = f = 0).
  const std::vector<Vec3> points = {{0, 0, 0}, {0, 0, 2}, {0, 0, -1e-300}, {-0.0, 0.0, 0}};
  for (VariationKind kind : AllVariations()) {
    Rng rng(1, 1);
    for (Vec3 p : points) {
      const Vec3 q = EvaluateVariation(Term(kind), p, Affine3::Identity(), rng);
      EXPECT_TRUE(IsFinite(q)) << VariationName(kind) << " at z=" << p.z;
    }
  }
}

constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr double kNan = std::numeric_limits<double>::quiet_NaN();

// Finite but far out: squares of the first three overflow, so formulas
// that form rho^2 or r^2 see infinity part-way.
const std::vector<Vec3>& HugePoints() {
  static const std::vector<Vec3> points = {
      {1e300, -1e300, 1e300}, {1e200, 3e200, -2e200}, {-1e160, 2e155, 7e170}, {1e20, -3e19, 5e18}};
  return points;
}
// Next to the origin and the z axis: squares underflow, some to zero.
const std::vector<Vec3>& TinyPoints() {
  static const std::vector<Vec3> points = {{1e-300, -2e-300, 5e-301}, {5e-324, -5e-324, 0},
                                           {0, -1e-320, 0.5},          {-1e-160, 1e-170, -1e-200},
                                           {0, 0, 1e-310},             {-1e-30, 2e-40, 3e-20}};
  return points;
}
const std::vector<Vec3>& InfinitePoints() {
  static const std::vector<Vec3> points = {{kInf, 0, 0},   {0, -kInf, 1},      {kInf, kInf, kInf},
                                           {-kInf, 0.5, 0.2}, {0.3, -0.7, kInf}, {0.3, -kInf, -kInf}};
  return points;
}
// NaN in the plane, with a finite z.
const std::vector<Vec3>& NanPoints() {
  static const std::vector<Vec3> points = {{kNan, 1, 2}, {0.3, kNan, 2}, {kNan, kNan, -0.5}};
  return points;
}

// Draws per call, as docs/variations.md fixes them.
int DocumentedDraws(VariationKind kind) {
  if (kind == VariationKind::kJulia) return 1;
  if (kind == VariationKind::kBlur || kind == VariationKind::kNoise) return 3;
  return 0;
}

Vec3 Eval(VariationKind kind, Vec3 p, uint64_t stream = 0) {
  Rng rng(13, stream);
  return EvaluateVariation(Term(kind), p, TestPre(), rng);
}

std::string At(VariationKind kind, Vec3 p) {
  return std::string(VariationName(kind)) + " at (" + std::to_string(p.x) + ", " +
         std::to_string(p.y) + ", " + std::to_string(p.z) + ")";
}

TEST(Variations, BoundedOnesStayInTheirBoundsForHugeInputs) {
  // docs/variations.md: sinusoidal folds space into [-1, 1]^3, cylinder
  // wraps x onto [-1, 1], bubble and blur land in the unit ball, fisheye in
  // the disc of radius 2, spherical inverts (|p| > 1 goes inside), noise
  // shrinks each coordinate, polar's x is the angle over pi. This holds
  // however far out the input is, even where squares overflow.
  using K = VariationKind;
  for (Vec3 p : HugePoints()) {
    const Vec3 sinus = Eval(K::kSinusoidal, p);
    for (int i = 0; i < 3; ++i) EXPECT_LE(std::abs(sinus[i]), 1.0) << At(K::kSinusoidal, p);
    const Vec3 cyl = Eval(K::kCylinder, p);
    EXPECT_LE(std::abs(cyl.x), 1.0) << At(K::kCylinder, p);
    EXPECT_EQ(cyl.y, p.y);
    EXPECT_EQ(cyl.z, p.z);
    for (K kind : {K::kBubble, K::kBlur, K::kSpherical}) {
      const Vec3 q = Eval(kind, p);
      EXPECT_TRUE(IsFinite(q)) << At(kind, p);
      EXPECT_LE(Length(q), 1.0) << At(kind, p);
    }
    const Vec3 fish = Eval(K::kFisheye, p);
    EXPECT_TRUE(IsFinite(fish)) << At(K::kFisheye, p);
    EXPECT_LE(std::hypot(fish.x, fish.y), 2.0) << At(K::kFisheye, p);
    EXPECT_EQ(fish.z, p.z);
    const Vec3 noise = Eval(K::kNoise, p);
    for (int i = 0; i < 3; ++i) EXPECT_LE(std::abs(noise[i]), std::abs(p[i])) << At(K::kNoise, p);
    const Vec3 polar = Eval(K::kPolar, p);
    EXPECT_GE(polar.x, -1.0) << At(K::kPolar, p);
    EXPECT_LE(polar.x, 1.0) << At(K::kPolar, p);
    EXPECT_EQ(Eval(K::kLinear, p), p);
  }
}

TEST(Variations, TinyInputsGiveFiniteResults) {
  // The eps guards keep every variation finite next to the origin and the
  // axis, where squares underflow (power's rho^(sin theta) stays below
  // 1 / rho, and rho is either 0 -- the axis, giving 1 -- or above 1e-154).
  for (VariationKind kind : AllVariations())
    for (Vec3 p : TinyPoints()) EXPECT_TRUE(IsFinite(Eval(kind, p))) << At(kind, p);
  for (Vec3 p : TinyPoints()) {
    if (std::max({std::abs(p.x), std::abs(p.y), std::abs(p.z)}) > 1e-10) continue;
    // Where the formulas are the identity to first order, exactly so.
    EXPECT_EQ(Eval(VariationKind::kLinear, p), p);
    EXPECT_EQ(Eval(VariationKind::kSinusoidal, p), p);
    EXPECT_EQ(Eval(VariationKind::kBubble, p), p);  // 4 / (r^2 + 4) = 1
    EXPECT_EQ(Eval(VariationKind::kPolar, p).y, -1.0);  // rho - 1
  }
  // On the axis proper the documented angle 0 applies: power gives 0^0 = 1.
  EXPECT_EQ(Eval(VariationKind::kPower, {0, 0, 1e-310}), (Vec3{1, 0, 1e-310}));
}

TEST(Variations, InfiniteInputsGiveNonFiniteResults) {
  // An infinite point must not come back finite, or the engine would keep
  // walking from a meaningless point instead of re-seeding. Exceptions:
  // blur ignores its input, and exponential at x = -inf returns its limit
  // e^-inf (cos, sin) = (0, 0).
  for (VariationKind kind : AllVariations()) {
    if (kind == VariationKind::kBlur) continue;
    for (Vec3 p : InfinitePoints()) {
      const Vec3 q = Eval(kind, p);
      if (kind == VariationKind::kExponential && p.x == -kInf)
        EXPECT_EQ(q, (Vec3{0, 0, p.z})) << At(kind, p);
      else
        EXPECT_FALSE(IsFinite(q)) << At(kind, p) << " gave (" << q.x << ", " << q.y << ", "
                                  << q.z << ")";
    }
  }
}

// A NaN point must not be taken for a point on the z axis (angle 0): spiral,
// hyperbolic, diamond, power and polar_doubling once returned finite points
// for it, so a pre-affine that overflowed to inf - inf = NaN escaped the
// engine's re-seeding.
TEST(Variations, NanInputsGiveNonFiniteResults) {
  for (VariationKind kind : AllVariations()) {
    if (kind == VariationKind::kBlur) continue;
    for (Vec3 p : NanPoints()) EXPECT_FALSE(IsFinite(Eval(kind, p))) << At(kind, p);
  }
}

TEST(Variations, DrawCountsDoNotDependOnTheInput) {
  // The number of draws per call is fixed, so a stream stays reproducible
  // even when a walker hits a degenerate point.
  std::vector<Vec3> points = HugePoints();
  for (const auto* set : {&TinyPoints(), &InfinitePoints(), &NanPoints()})
    points.insert(points.end(), set->begin(), set->end());
  for (VariationKind kind : AllVariations()) {
    for (Vec3 p : points) {
      Rng rng(21, 4), twin(21, 4);
      (void)EvaluateVariation(Term(kind), p, TestPre(), rng);
      for (int i = 0; i < DocumentedDraws(kind); ++i) (void)twin.Next();
      EXPECT_EQ(rng.Next(), twin.Next()) << At(kind, p);
    }
  }
}

TEST(Variations, BlurIgnoresItsInputWhateverItIs) {
  const Vec3 ordinary = Eval(VariationKind::kBlur, {0.3, -0.2, 0.1}, 9);
  for (const auto* set : {&HugePoints(), &TinyPoints(), &InfinitePoints(), &NanPoints()})
    for (Vec3 p : *set) EXPECT_EQ(Eval(VariationKind::kBlur, p, 9), ordinary) << At(VariationKind::kBlur, p);
  EXPECT_LE(Length(ordinary), 1.0);
}

TEST(Variations, PlanarOnesPassZThroughWhateverXAndYAre) {
  // z' = z (polar_doubling: z / sqrt 2) bit for bit, and the planar part
  // ignores z even when z is infinite or NaN.
  std::vector<Vec3> points = HugePoints();
  for (const auto* set : {&TinyPoints(), &InfinitePoints(), &NanPoints()})
    points.insert(points.end(), set->begin(), set->end());
  for (VariationKind kind : AllVariations()) {
    if (!GetVariationInfo(kind).planar) continue;
    for (Vec3 p : points) {
      if (!std::isfinite(p.z)) continue;
      const double want = kind == VariationKind::kPolarDoubling ? p.z / std::sqrt(2.0) : p.z;
      EXPECT_DOUBLE_EQ(Eval(kind, p).z, want) << At(kind, p);
      if (kind != VariationKind::kPolarDoubling) {
        EXPECT_EQ(Eval(kind, p).z, p.z) << At(kind, p);
      }
    }
    for (Vec3 p : SamplePoints()) {
      for (double z : {kInf, -kInf, kNan}) {
        const Vec3 a = Eval(kind, p), b = Eval(kind, {p.x, p.y, z});
        EXPECT_EQ(a.x, b.x) << At(kind, p) << " with z = " << z;
        EXPECT_EQ(a.y, b.y) << At(kind, p) << " with z = " << z;
      }
    }
  }
}

// A one-map chaos game on [-1, 1]^3 whose only map sends every point to
// infinity: exponential of x + 800 overflows for any x > -89.
ChaosGameParams AlwaysOverflows(uint64_t iterations, uint32_t warmup) {
  ChaosGameParams p;
  PointMap m;
  m.pre = Affine3::Translate({800, 0, 0});
  m.variations = {Term(VariationKind::kExponential)};
  p.ifs.maps = {m};
  p.ifs.probabilities = {1};
  p.frame = {{8, 8, 8}, {{-1, -1, -1}, {1, 1, 1}}};
  p.iterations = iterations;
  p.warmup = warmup;
  return p;
}

TEST(Variations, EngineReseedsWalkersAVariationSendsToInfinity) {
  // Every step fails: each of the 64 walkers of a flame's chunk re-seeds
  // once per warm-up step, and each plotted step re-seeds and warms up
  // again instead of plotting. 64 x 3 + 100 x (1 + 3) = 592.
  auto game = ChaosGame::Create(AlwaysOverflows(100, 3), 2);
  ASSERT_TRUE(game.ok()) << game.status();
  ASSERT_TRUE((*game)->Run(nullptr).ok());
  const ChaosGameStats s = (*game)->stats();
  EXPECT_EQ(s.reseeded, 592u);
  EXPECT_EQ(s.iterations_done, 100u);
  EXPECT_EQ(s.outside, 0u);
  EXPECT_EQ(s.final_nonfinite, 0u);
  EXPECT_EQ((*game)->TakeCounts().Total(), 0u);
}

TEST(Variations, EngineDropsPointsAFinalVariationSendsToInfinity) {
  // The same overflow in the final transform only: walkers never re-seed,
  // every plotted point is counted as non-finite and outside.
  ChaosGameParams p = AlwaysOverflows(100, 3);
  p.ifs.final_map = p.ifs.maps[0];
  p.ifs.maps[0].pre = Affine3::Scale({0.5, 0.5, 0.5});
  p.ifs.maps[0].variations = {Term(VariationKind::kSinusoidal)};
  auto game = ChaosGame::Create(p, 1);
  ASSERT_TRUE(game.ok()) << game.status();
  ASSERT_TRUE((*game)->Run(nullptr).ok());
  const ChaosGameStats s = (*game)->stats();
  EXPECT_EQ(s.reseeded, 0u);
  EXPECT_EQ(s.final_nonfinite, 100u);
  EXPECT_EQ(s.outside, 100u);
  EXPECT_EQ((*game)->TakeCounts().Total(), 0u);
}

TEST(Variations, PlanarOnesPassZThrough) {
  Rng rng(2, 2);
  for (VariationKind kind : AllVariations()) {
    const VariationInfo& info = GetVariationInfo(kind);
    if (!info.planar || kind == VariationKind::kPolarDoubling) continue;
    for (Vec3 p : SamplePoints())
      EXPECT_EQ(EvaluateVariation(Term(kind), p, TestPre(), rng).z, p.z) << info.name;
  }
}

TEST(Variations, InfoFlagsMatchBehaviour) {
  const Vec3 p{0.6, -0.9, 0.35};
  Affine3 other_pre = TestPre();
  other_pre.m[0][1] = -1.3;
  other_pre.m[0][3] = 0.9;
  other_pre.m[1][1] = 0.15;
  other_pre.m[1][3] = 0.6;
  for (VariationKind kind : AllVariations()) {
    const VariationInfo& info = GetVariationInfo(kind);
    EXPECT_EQ(info.name, VariationName(kind));
    EXPECT_EQ(info.param_count, 0) << info.name;
    const bool want_random = kind == VariationKind::kJulia || kind == VariationKind::kBlur ||
                             kind == VariationKind::kNoise;
    EXPECT_EQ(info.random, want_random) << info.name;
    if (info.random) continue;
    // Deterministic ones must leave the stream untouched.
    Rng rng(6, 6), untouched(6, 6);
    const Vec3 a = EvaluateVariation(Term(kind), p, TestPre(), rng);
    EXPECT_EQ(rng.Next(), untouched.Next()) << info.name;
    // Only the dependent ones look at the pre-affine.
    const Vec3 b = EvaluateVariation(Term(kind), p, other_pre, rng);
    EXPECT_EQ(a != b, info.reads_pre) << info.name;
  }
}

TEST(VariationNames, CanonicalNamesInEnumOrder) {
  const std::vector<std::string> names = {
      "linear", "sinusoidal", "spherical", "swirl",         "horseshoe",   "polar", "handkerchief",
      "heart",  "disc",       "spiral",    "hyperbolic",    "diamond",     "ex",    "julia",
      "bent",   "waves",      "fisheye",   "popcorn",       "exponential", "power", "cylinder",
      "bubble", "blur",       "noise",     "polar_doubling"};
  const std::vector<VariationKind>& all = AllVariations();
  ASSERT_EQ(all.size(), 25u);
  for (size_t i = 0; i < all.size(); ++i) {
    EXPECT_EQ(static_cast<size_t>(all[i]), i);
    EXPECT_EQ(VariationName(all[i]), names[i]);
  }
  EXPECT_EQ(all.back(), VariationKind::kPolarDoubling);
}

TEST(VariationNames, RoundTrip) {
  for (VariationKind kind : AllVariations()) {
    const std::optional<VariationKind> back = VariationFromName(VariationName(kind));
    ASSERT_TRUE(back.has_value()) << VariationName(kind);
    EXPECT_EQ(*back, kind);
  }
}

TEST(VariationNames, UnknownOrInexactNamesAreRejected) {
  for (const char* name : {"", "unknown", "Linear", "SWIRL", "polar-doubling", "polardoubling",
                           "polar doubling", " linear", "linear ", "julian", "lin"})
    EXPECT_FALSE(VariationFromName(name).has_value()) << '"' << name << '"';
}

}  // namespace
}  // namespace nimbus
