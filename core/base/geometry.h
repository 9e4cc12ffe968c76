// Small value types for 3D points and affine maps. Header-only and free of
// OpenVDB so that every module can include it cheaply.
#pragma once

#include <array>
#include <cmath>
#include <cstdint>

namespace nimbus {

struct Vec3 {
  double x = 0, y = 0, z = 0;

  constexpr double& operator[](int i) { return i == 0 ? x : (i == 1 ? y : z); }
  constexpr double operator[](int i) const { return i == 0 ? x : (i == 1 ? y : z); }
  friend constexpr Vec3 operator+(Vec3 a, Vec3 b) { return {a.x + b.x, a.y + b.y, a.z + b.z}; }
  friend constexpr Vec3 operator-(Vec3 a, Vec3 b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
  friend constexpr Vec3 operator*(double s, Vec3 a) { return {s * a.x, s * a.y, s * a.z}; }
  friend constexpr Vec3 operator*(Vec3 a, double s) { return s * a; }
  friend constexpr bool operator==(Vec3 a, Vec3 b) = default;
};

inline double Dot(Vec3 a, Vec3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
inline Vec3 Cross(Vec3 a, Vec3 b) {
  return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
inline double Length(Vec3 a) { return std::sqrt(Dot(a, a)); }
inline bool IsFinite(Vec3 a) {
  return std::isfinite(a.x) && std::isfinite(a.y) && std::isfinite(a.z);
}

/// @brief A 3D affine map p' = A p + b, stored as a row-major 3x4 matrix
/// [A | b]. Composition follows function notation: (f * g)(p) = f(g(p)).
struct Affine3 {
  // m[r][c]; column 3 is the translation.
  std::array<std::array<double, 4>, 3> m{{{1, 0, 0, 0}, {0, 1, 0, 0}, {0, 0, 1, 0}}};

  static Affine3 Identity() { return {}; }
  static Affine3 Translate(Vec3 t);
  static Affine3 Scale(Vec3 s);
  /// Rotation by `degrees` about `axis` (right-handed); axis need not be unit.
  /// Returns identity for a zero axis; callers validate the axis first.
  static Affine3 Rotate(Vec3 axis, double degrees);
  /// Shear: x' = x + xy*y + xz*z, y' = y + yx*x + yz*z, z' = z + zx*x + zy*y.
  static Affine3 Shear(double xy, double xz, double yx, double yz, double zx, double zy);

  Vec3 Apply(Vec3 p) const {
    return {m[0][0] * p.x + m[0][1] * p.y + m[0][2] * p.z + m[0][3],
            m[1][0] * p.x + m[1][1] * p.y + m[1][2] * p.z + m[1][3],
            m[2][0] * p.x + m[2][1] * p.y + m[2][2] * p.z + m[2][3]};
  }
  Vec3 ApplyLinear(Vec3 p) const {
    return {m[0][0] * p.x + m[0][1] * p.y + m[0][2] * p.z,
            m[1][0] * p.x + m[1][1] * p.y + m[1][2] * p.z,
            m[2][0] * p.x + m[2][1] * p.y + m[2][2] * p.z};
  }
  Vec3 translation() const { return {m[0][3], m[1][3], m[2][3]}; }

  /// Determinant of the linear part; |det| is the map's volume scale factor.
  double Determinant() const;
  /// Largest singular value of the linear part: the map's Lipschitz constant.
  /// A map is a contraction iff this is < 1.
  double ContractionFactor() const;
  /// Smallest singular value of the linear part: below 1 some direction
  /// shrinks.
  double SmallestSingularValue() const;

  friend Affine3 operator*(const Affine3& f, const Affine3& g);  // f after g
  friend bool operator==(const Affine3& a, const Affine3& b) = default;
};

/// @brief Axis-aligned world-space box.
struct Bounds {
  Vec3 min, max;
  Vec3 Size() const { return max - min; }
  bool Contains(Vec3 p) const {
    return p.x >= min.x && p.x <= max.x && p.y >= min.y && p.y <= max.y && p.z >= min.z &&
           p.z <= max.z;
  }
};

/// @brief Integer 3D resolution or index.
struct Int3 {
  int32_t x = 0, y = 0, z = 0;
  constexpr int32_t operator[](int i) const { return i == 0 ? x : (i == 1 ? y : z); }
  int64_t Volume() const { return int64_t{x} * y * z; }
  friend constexpr bool operator==(Int3 a, Int3 b) = default;
};

/// @brief A voxel lattice laid over world-space bounds: voxel (i,j,k) covers
/// [min + i*h, min + (i+1)*h) per axis, h = size / resolution.
struct GridFrame {
  Int3 resolution;
  Bounds bounds;

  Vec3 VoxelSize() const {
    Vec3 s = bounds.Size();
    return {s.x / resolution.x, s.y / resolution.y, s.z / resolution.z};
  }
  Vec3 VoxelCenter(Int3 v) const {
    Vec3 h = VoxelSize();
    return {bounds.min.x + (v.x + 0.5) * h.x, bounds.min.y + (v.y + 0.5) * h.y,
            bounds.min.z + (v.z + 0.5) * h.z};
  }
};

}  // namespace nimbus
