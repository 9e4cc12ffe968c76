#include "core/chaos/random_ifs.h"

#include <algorithm>
#include <cmath>

#include "core/base/random.h"

namespace nimbus {

namespace {

// Keeps the explorer's streams apart from the chaos game's (seed, chunk).
constexpr uint64_t kExploreStream = 0x6578706c6f726531ULL;  // "explore1"

// Largest singular value of [[a, b], [c, d]]: the square root of the
// larger eigenvalue of its Gram matrix, (T + sqrt(T^2 - 4 D^2)) / 2 with T
// the squared Frobenius norm and D the determinant.
double SingularValue2(double a, double b, double c, double d) {
  const double t = a * a + b * b + c * c + d * d;
  const double det = a * d - b * c;
  const double disc = std::max(t * t - 4 * det * det, 0.0);
  return std::sqrt(0.5 * (t + std::sqrt(disc)));
}

// The inverse of a rotation.
Affine3 Transpose(const Affine3& r) {
  Affine3 t;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) t.m[i][j] = r.m[j][i];
  return t;
}

}  // namespace

Affine3 SolidViewRotation() {
  return Affine3::Rotate({1, 0, 0}, 25) * Affine3::Rotate({0, 1, 0}, -35);
}

std::vector<PointMap> DrawRandomIfs(const RandomIfsParams& p, uint64_t seed, uint64_t attempt) {
  Rng rng(seed ^ kExploreStream, attempt);
  const int span = p.max_maps - p.min_maps + 1;
  const int n = p.min_maps + int(rng.Uniform() * span) % span;
  const int dims = p.dimensions == 3 ? 3 : 2;
  const double r = p.coefficient_range, t = p.translation_range;
  std::vector<PointMap> maps(static_cast<size_t>(n));
  for (int i = 0; i < n; ++i) {
    Affine3& a = maps[size_t(i)].pre;
    a = Affine3::Identity();
    for (int row = 0; row < dims; ++row) {
      for (int col = 0; col < dims; ++col) a.m[row][col] = rng.Uniform(-r, r);
      a.m[row][3] = rng.Uniform(-t, t);
    }
    if (dims == 2) a.m[2][2] = kPlanarZScale;
    // A solid IFS is turned so that the view along -z sees it obliquely:
    // R (A p + b) composed with R^T is the same attractor, turned.
    if (dims == 3) a = SolidViewRotation() * a * Transpose(SolidViewRotation());
    // Always draw, so a map's coefficients do not depend on the list.
    const double pick = rng.Uniform();
    const double which = rng.Uniform();
    if (!p.variations.empty() && pick < p.variation_probability) {
      const size_t k = std::min(p.variations.size() - 1, size_t(which * p.variations.size()));
      maps[size_t(i)].variations.push_back(VariationTerm{p.variations[k], 1.0, {}});
    }
    maps[size_t(i)].color = n > 1 ? double(i) / double(n - 1) : 0.0;
  }
  return maps;
}

double MapContraction(const Affine3& a, int dimensions, ContractionMeasure measure) {
  if (dimensions == 2) {
    if (measure == ContractionMeasure::kDeterminant)
      return std::fabs(a.m[0][0] * a.m[1][1] - a.m[0][1] * a.m[1][0]);
    return SingularValue2(a.m[0][0], a.m[0][1], a.m[1][0], a.m[1][1]);
  }
  if (measure == ContractionMeasure::kDeterminant) return std::fabs(a.Determinant());
  return a.ContractionFactor();
}

double IfsContraction(const std::vector<PointMap>& maps, int dimensions,
                      ContractionMeasure measure) {
  double out = 0;
  for (const PointMap& m : maps) {
    const double c = MapContraction(m.pre, dimensions, measure);
    out = measure == ContractionMeasure::kDeterminant ? out + c : std::max(out, c);
  }
  return out;
}

}  // namespace nimbus
