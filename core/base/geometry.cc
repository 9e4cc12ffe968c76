#include "core/base/geometry.h"

#include <algorithm>

namespace nimbus {

Affine3 Affine3::Translate(Vec3 t) {
  Affine3 a;
  a.m[0][3] = t.x;
  a.m[1][3] = t.y;
  a.m[2][3] = t.z;
  return a;
}

Affine3 Affine3::Scale(Vec3 s) {
  Affine3 a;
  a.m[0][0] = s.x;
  a.m[1][1] = s.y;
  a.m[2][2] = s.z;
  return a;
}

Affine3 Affine3::Rotate(Vec3 axis, double degrees) {
  const double len = Length(axis);
  if (len == 0) return {};
  const Vec3 u = (1.0 / len) * axis;
  const double th = degrees * (M_PI / 180.0);
  const double c = std::cos(th), s = std::sin(th), t = 1 - c;
  Affine3 a;
  a.m[0] = {t * u.x * u.x + c, t * u.x * u.y - s * u.z, t * u.x * u.z + s * u.y, 0};
  a.m[1] = {t * u.x * u.y + s * u.z, t * u.y * u.y + c, t * u.y * u.z - s * u.x, 0};
  a.m[2] = {t * u.x * u.z - s * u.y, t * u.y * u.z + s * u.x, t * u.z * u.z + c, 0};
  return a;
}

Affine3 Affine3::Shear(double xy, double xz, double yx, double yz, double zx, double zy) {
  Affine3 a;
  a.m[0][1] = xy;
  a.m[0][2] = xz;
  a.m[1][0] = yx;
  a.m[1][2] = yz;
  a.m[2][0] = zx;
  a.m[2][1] = zy;
  return a;
}

Affine3 operator*(const Affine3& f, const Affine3& g) {
  Affine3 r;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 4; ++j) {
      double v = (j == 3) ? f.m[i][3] : 0.0;
      for (int k = 0; k < 3; ++k) v += f.m[i][k] * g.m[k][j];
      r.m[i][j] = v;
    }
  }
  return r;
}

double Affine3::Determinant() const {
  return m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) -
         m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0]) +
         m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
}

namespace {

// Eigenvalues of the symmetric 3x3 matrix A^T A (the squared singular values
// of A), smallest first, by the closed-form trigonometric solution.
std::array<double, 3> GramEigenvalues(const Affine3& a) {
  double s[3][3];
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) {
      double v = 0;
      for (int k = 0; k < 3; ++k) v += a.m[k][i] * a.m[k][j];
      s[i][j] = v;
    }
  const double p1 = s[0][1] * s[0][1] + s[0][2] * s[0][2] + s[1][2] * s[1][2];
  std::array<double, 3> e;
  if (p1 <= 1e-300) {
    e = {s[0][0], s[1][1], s[2][2]};
  } else {
    const double q = (s[0][0] + s[1][1] + s[2][2]) / 3.0;
    const double p2 = (s[0][0] - q) * (s[0][0] - q) + (s[1][1] - q) * (s[1][1] - q) +
                      (s[2][2] - q) * (s[2][2] - q) + 2 * p1;
    const double p = std::sqrt(p2 / 6.0);
    double b[3][3];
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) b[i][j] = (s[i][j] - (i == j ? q : 0)) / p;
    const double detb = b[0][0] * (b[1][1] * b[2][2] - b[1][2] * b[2][1]) -
                        b[0][1] * (b[1][0] * b[2][2] - b[1][2] * b[2][0]) +
                        b[0][2] * (b[1][0] * b[2][1] - b[1][1] * b[2][0]);
    const double phi = std::acos(std::clamp(detb / 2.0, -1.0, 1.0)) / 3.0;
    const double largest = q + 2 * p * std::cos(phi);
    const double smallest = q + 2 * p * std::cos(phi + 2 * M_PI / 3);
    e = {smallest, 3 * q - largest - smallest, largest};
  }
  std::sort(e.begin(), e.end());
  return e;
}

}  // namespace

double Affine3::ContractionFactor() const {
  return std::sqrt(std::max(GramEigenvalues(*this)[2], 0.0));
}

double Affine3::SmallestSingularValue() const {
  return std::sqrt(std::max(GramEigenvalues(*this)[0], 0.0));
}

}  // namespace nimbus
