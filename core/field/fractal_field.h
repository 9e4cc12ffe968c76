// @brief A fractal field: the weighted sum of random values interpolated
// on n-dimensional lattices (meshes) of shrinking cell size, n = 1..4
// (docs/fractal_fields.md). This header holds the parameters, the mapping
// from space and time to field coordinates, and the point evaluator, which
// follows the reference description step by step; field_grid.h evaluates
// whole grids fast.
//
//   FractalField f(params);                      // params checked by Validate
//   double v = f.Sample({x, y, z}, t);
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include "absl/status/status.h"

namespace nimbus {

inline constexpr int kMaxFieldDims = 4;
inline constexpr int kMaxFieldMeshes = 64;

using FieldVec = std::array<double, kMaxFieldDims>;

enum class FieldInterpolation {
  kLinear,       // n-linear over the 2^n nodes of the cell
  kPseudoCubic,  // the reference's pseudo n-cubic (Hermite per axis in turn,
                 // derivatives carried linearly): C1 across the faces of the
                 // last axis only
  kQuintic,      // n-linear with the weights eased by 6t^5 - 15t^4 + 10t^3
  kCubic,        // the tensor product of cubic Hermite (Catmull-Rom) steps
                 // over the 4^n nodes around the cell: C1 across every face
};

/// True for the interpolations that read 4 nodes per axis.
inline bool FourTap(FieldInterpolation i) {
  return i == FieldInterpolation::kPseudoCubic || i == FieldInterpolation::kCubic;
}

/// @brief One lattice. Mesh coordinates are m_i = (R u)_i / cell_i +
/// offset_i, node (floor m); on a periodic axis node indices wrap modulo
/// `period_nodes`, so the lattice repeats exactly.
struct FieldMesh {
  FieldVec cell{1, 1, 1, 1};
  FieldVec offset{0, 0, 0, 0};  // in cells
  /// Rotation of the spatial axes (row-major 3x3, identity when unrotated).
  std::array<std::array<double, 3>, 3> rotation{{{1, 0, 0}, {0, 1, 0}, {0, 0, 1}}};
  bool rotated = false;
  double weight = 1;
  /// Nodes per period on each axis; 0 = not periodic.
  std::array<int64_t, kMaxFieldDims> period_nodes{0, 0, 0, 0};
};

enum class WindKind { kNone, kLinear, kSine };

/// @brief δ(t), added to the spatial field coordinates: linear velocity·t,
/// or amplitude·sin(2π t / sine_period + phase).
struct Wind {
  WindKind kind = WindKind::kNone;
  std::array<double, 3> velocity{0, 0, 0};
  std::array<double, 3> amplitude{0, 0, 0};
  double sine_period = 1;
  double phase_radians = 0;
};

/// @brief Space (x, up to 3 axes) and time t to field coordinates u:
/// u_i = Σ_j matrix[i][j] x_j + offset_i + δ_i(t) for the spatial axes,
/// u_s = t for the time axis (when dims = space_dims + 1); then every axis
/// with period[i] > 0 wraps into [0, period[i]).
struct FieldMapping {
  int space_dims = 3;
  std::array<std::array<double, 3>, 3> matrix{{{1, 0, 0}, {0, 1, 0}, {0, 0, 1}}};
  std::array<double, 3> offset{0, 0, 0};
  Wind wind;
  FieldVec period{0, 0, 0, 0};

  bool Diagonal() const;
};

struct FractalFieldParams {
  int dims = 3;
  std::vector<FieldMesh> meshes;
  FieldInterpolation interpolation = FieldInterpolation::kLinear;
  uint64_t seed = 0;
  FieldMapping mapping;
};

/// Checks dimensions, meshes (count, cells > 0, finite weights and
/// offsets, periods consistent with the mapping) so the engine can trust
/// them. Messages name the part ("meshes[2].cell[0]: must be > 0").
absl::Status ValidateFieldParams(const FractalFieldParams& params);

/// Wraps x into [0, period) exactly (fmod is exact); period <= 0: x.
double WrapPeriodic(double x, double period);

/// @brief The point evaluator. Thread-safe (const).
class FractalField {
 public:
  explicit FractalField(FractalFieldParams params);

  const FractalFieldParams& params() const { return p_; }
  int dims() const { return p_.dims; }
  /// Σ |weight|: the field lies in [-WeightSum, WeightSum].
  double WeightSum() const { return weight_sum_; }

  /// Field coordinates of the space point x (space_dims values) at time t.
  FieldVec Map(const double* x, double t) const;
  /// Σ_k weight_k f_k(u) at field coordinates u (already mapped).
  double Eval(const FieldVec& u) const;
  /// f_k(u): mesh k's interpolated value, unweighted.
  double EvalMesh(size_t k, const FieldVec& u) const;
  /// Eval(Map(x, t)).
  double Sample(const double* x, double t) const { return Eval(Map(x, t)); }
  /// Mesh coordinates m of u on mesh k (before flooring).
  FieldVec MeshCoords(size_t k, const FieldVec& u) const;
  /// RDN at node `node` (field axes) of mesh k, periodic wrapping applied.
  float Node(size_t k, const int64_t* node) const;
  /// Where field axis `axis` goes in NodeSlots: 0..2 spatial, 3 time.
  int SlotOf(int axis) const { return axis < p_.mapping.space_dims ? axis : 3; }

 private:
  FractalFieldParams p_;
  double weight_sum_ = 0;
};

/// The weights of the Hermite basis at t: value at 0 and 1, derivative at 0
/// and 1 (h00, h01, h10, h11).
std::array<double, 4> HermiteBasis(double t);
/// 6t^5 - 15t^4 + 10t^3.
double QuinticFade(double t);
/// Catmull-Rom weights of nodes -1, 0, 1, 2 at t: the cubic Hermite with
/// central-difference derivatives.
std::array<double, 4> CatmullRom(double t);

}  // namespace nimbus
