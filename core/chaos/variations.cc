// Flame-style variations in 3D: the facts table and the scalar entry point.
// The formulas themselves are in variation_formulas.h (shared with the SIMD
// flame kernels); docs/variations.md is the reference for every formula and
// for the conventions: planar variations measure the angle as flam3 does,
// theta = atan2(x, y), and pass z through; the 3D ones use r = |p|.
#include "core/chaos/variations.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>

#include "core/chaos/variation_formulas.h"

namespace nimbus {
namespace {

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

// The engine's draws for the formulas: Bit() is the top bit of one raw word.
struct RngDraws {
  Rng& rng;
  double Uniform() { return rng.Uniform(); }
  bool Bit() { return (rng.Next() >> 63) != 0; }
};

// Pre-drawn words, read as RngDraws reads fresh ones.
struct WordDraws {
  const uint64_t* next;
  double Uniform() { return double(*next++ >> 11) * 0x1.0p-53; }
  bool Bit() { return (*next++ >> 63) != 0; }
};

// The shared formulas on one point, with the map's pre-affine as 12 numbers.
template <class Draws>
Vec3 Evaluate(VariationKind kind, Vec3 p, const Affine3& pre, Draws& draws) {
  const double coef[12] = {pre.m[0][0], pre.m[0][1], pre.m[0][2], pre.m[0][3],
                           pre.m[1][0], pre.m[1][1], pre.m[1][2], pre.m[1][3],
                           pre.m[2][0], pre.m[2][1], pre.m[2][2], pre.m[2][3]};
  const formulas::P3<double> q = formulas::Variation<double>(kind, {p.x, p.y, p.z}, coef, draws);
  return {q.x, q.y, q.z};
}

}  // namespace

Vec3 EvaluateVariation(const VariationTerm& v, Vec3 p, const Affine3& pre,
                       const uint64_t* words) {
  WordDraws draws{words};
  return Evaluate(v.kind, p, pre, draws);
}

int VariationWords(VariationKind kind) { return formulas::VariationDraws(kind); }

Vec3 EvaluateVariation(const VariationTerm& v, Vec3 p, const Affine3& pre, Rng& rng) {
  RngDraws draws{rng};
  return Evaluate(v.kind, p, pre, draws);
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
