#include "core/field/fractal_field.h"

#include <cmath>
#include <string>

#include "absl/strings/str_cat.h"
#include "core/field/node_hash.h"

namespace nimbus {

namespace {

using absl::StrCat;

absl::Status Bad(const std::string& path, const std::string& what) {
  return absl::InvalidArgumentError(StrCat(path, ": ", what));
}

absl::Status ValidateMesh(const FractalFieldParams& p, size_t k) {
  const FieldMesh& m = p.meshes[k];
  const std::string path = StrCat("meshes[", k, "]");
  for (int i = 0; i < p.dims; ++i) {
    if (!(std::isfinite(m.cell[i]) && m.cell[i] > 0))
      return Bad(StrCat(path, ".cell[", i, "]"), StrCat("must be finite and > 0, got ", m.cell[i]));
    if (!std::isfinite(m.offset[i])) return Bad(StrCat(path, ".offset[", i, "]"), "must be finite");
    const bool periodic = p.mapping.period[i] > 0;
    if (periodic != (m.period_nodes[i] > 0))
      return Bad(StrCat(path, ".period_nodes[", i, "]"),
                 "must be set exactly on the mapping's periodic axes");
  }
  if (!std::isfinite(m.weight)) return Bad(path + ".weight", "must be finite");
  if (m.rotated)
    for (int i = 0; i < p.mapping.space_dims; ++i)
      if (p.mapping.period[i] > 0)
        return Bad(path + ".rotation", "a rotated mesh cannot be periodic");
  return absl::OkStatus();
}

}  // namespace

bool FieldMapping::Diagonal() const {
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      if (i != j && matrix[i][j] != 0) return false;
  return true;
}

absl::Status ValidateFieldParams(const FractalFieldParams& p) {
  const int s = p.mapping.space_dims;
  if (s < 1 || s > 3) return Bad("space_dims", StrCat("must be 1..3, got ", s));
  if (p.dims != s && p.dims != s + 1)
    return Bad("dims", StrCat("must be the space's ", s, " axes, or ", s + 1,
                              " with time; got ", p.dims));
  if (p.meshes.empty()) return Bad("meshes", "need at least one mesh");
  if (p.meshes.size() > size_t(kMaxFieldMeshes))
    return Bad("meshes", StrCat("at most ", kMaxFieldMeshes, ", got ", p.meshes.size()));
  for (int i = 0; i < p.dims; ++i)
    if (!(std::isfinite(p.mapping.period[i]) && p.mapping.period[i] >= 0))
      return Bad(StrCat("mapping.period[", i, "]"), "must be finite and >= 0");
  for (size_t k = 0; k < p.meshes.size(); ++k)
    if (absl::Status st = ValidateMesh(p, k); !st.ok()) return st;
  return absl::OkStatus();
}

double WrapPeriodic(double x, double period) {
  if (!(period > 0)) return x;
  double r = std::fmod(x, period);
  if (r < 0) r += period;
  // -tiny + period rounds to period itself: the top of the interval is 0.
  return r >= period ? 0.0 : r;
}

std::array<double, 4> HermiteBasis(double t) {
  const double t2 = t * t, t3 = t2 * t;
  return {2 * t3 - 3 * t2 + 1, -2 * t3 + 3 * t2, t3 - 2 * t2 + t, t3 - t2};
}

double QuinticFade(double t) { return t * t * t * (t * (t * 6 - 15) + 10); }

std::array<double, 4> CatmullRom(double t) {
  const auto h = HermiteBasis(t);
  return {-h[2] / 2, h[0] - h[3] / 2, h[1] + h[2] / 2, h[3] / 2};
}

FractalField::FractalField(FractalFieldParams params) : p_(std::move(params)) {
  for (const FieldMesh& m : p_.meshes) weight_sum_ += std::abs(m.weight);
}

FieldVec FractalField::Map(const double* x, double t) const {
  const FieldMapping& m = p_.mapping;
  const int s = m.space_dims;
  FieldVec u{0, 0, 0, 0};
  for (int i = 0; i < s; ++i) {
    double v = m.offset[i];
    for (int j = 0; j < s; ++j) v += m.matrix[i][j] * x[j];
    if (m.wind.kind == WindKind::kLinear) v += m.wind.velocity[i] * t;
    if (m.wind.kind == WindKind::kSine)
      v += m.wind.amplitude[i] *
           std::sin(2 * M_PI * t / m.wind.sine_period + m.wind.phase_radians);
    u[i] = v;
  }
  if (p_.dims > s) u[s] = t;
  for (int i = 0; i < p_.dims; ++i) u[i] = WrapPeriodic(u[i], m.period[i]);
  return u;
}

FieldVec FractalField::MeshCoords(size_t k, const FieldVec& u) const {
  const FieldMesh& mesh = p_.meshes[k];
  FieldVec r = u;
  if (mesh.rotated) {
    const int s = p_.mapping.space_dims;
    for (int i = 0; i < s; ++i) {
      r[i] = 0;
      for (int j = 0; j < s; ++j) r[i] += mesh.rotation[i][j] * u[j];
    }
  }
  FieldVec m{0, 0, 0, 0};
  for (int i = 0; i < p_.dims; ++i) m[i] = r[i] / mesh.cell[i] + mesh.offset[i];
  return m;
}

float FractalField::Node(size_t k, const int64_t* node) const {
  const FieldMesh& mesh = p_.meshes[k];
  int64_t slots[4] = {0, 0, 0, 0};
  for (int i = 0; i < p_.dims; ++i) {
    const int64_t per = mesh.period_nodes[i];
    slots[SlotOf(i)] = per > 0 ? ((node[i] % per) + per) % per : node[i];
  }
  return NodeValue(p_.seed, uint32_t(k), {slots[0], slots[1], slots[2], slots[3]});
}

double FractalField::EvalMesh(size_t k, const FieldVec& u) const {
  const int n = p_.dims;
  const FieldVec m = MeshCoords(k, u);
  int64_t base[kMaxFieldDims] = {0, 0, 0, 0};
  double t[kMaxFieldDims] = {0, 0, 0, 0};
  for (int i = 0; i < n; ++i) {
    const double f = std::floor(m[i]);
    base[i] = int64_t(f);
    t[i] = m[i] - f;
  }
  const int corners = 1 << n;
  if (p_.interpolation == FieldInterpolation::kCubic) {
    // The tensor product over the 4^n nodes around the cell.
    std::array<double, 4> w[kMaxFieldDims];
    for (int i = 0; i < n; ++i) w[i] = CatmullRom(t[i]);
    double sum = 0;
    for (int c = 0; c < (1 << (2 * n)); ++c) {
      int64_t node[kMaxFieldDims];
      double wc = 1;
      for (int i = 0; i < n; ++i) {
        const int d = (c >> (2 * i)) & 3;
        node[i] = base[i] + d - 1;
        wc *= w[i][size_t(d)];
      }
      sum += wc * Node(k, node);
    }
    return sum;
  }
  if (p_.interpolation != FieldInterpolation::kPseudoCubic) {
    // n-linear (eased for quintic) over the 2^n corners.
    double sum = 0;
    for (int c = 0; c < corners; ++c) {
      int64_t node[kMaxFieldDims];
      double w = 1;
      for (int i = 0; i < n; ++i) {
        const int bit = (c >> i) & 1;
        node[i] = base[i] + bit;
        const double ti = p_.interpolation == FieldInterpolation::kQuintic ? QuinticFade(t[i]) : t[i];
        w *= bit ? ti : 1 - ti;
      }
      sum += w * Node(k, node);
    }
    return sum;
  }
  // Pseudo n-cubic, as the reference describes it: at every corner the node
  // value and central-difference derivatives; then along axis 0, 1, ... in
  // turn, a cubic Hermite for the value and linear interpolation for the
  // derivatives along the axes still to come.
  double val[16], der[16][kMaxFieldDims];
  for (int c = 0; c < corners; ++c) {
    int64_t node[kMaxFieldDims];
    for (int i = 0; i < n; ++i) node[i] = base[i] + ((c >> i) & 1);
    val[c] = Node(k, node);
    for (int i = 0; i < n; ++i) {
      int64_t a[kMaxFieldDims], b[kMaxFieldDims];
      for (int j = 0; j < n; ++j) a[j] = b[j] = node[j];
      ++a[i];
      --b[i];
      der[c][i] = (double(Node(k, a)) - double(Node(k, b))) / 2;
    }
  }
  for (int axis = 0, count = corners; axis < n; ++axis, count >>= 1) {
    const auto h = HermiteBasis(t[axis]);
    for (int c = 0; c < count / 2; ++c) {
      const int lo = 2 * c, hi = 2 * c + 1;
      const double v = h[0] * val[lo] + h[1] * val[hi] + h[2] * der[lo][axis] + h[3] * der[hi][axis];
      for (int j = axis + 1; j < n; ++j)
        der[c][j] = (1 - t[axis]) * der[lo][j] + t[axis] * der[hi][j];
      val[c] = v;
    }
  }
  return val[0];
}

double FractalField::Eval(const FieldVec& u) const {
  double sum = 0;
  for (size_t k = 0; k < p_.meshes.size(); ++k) sum += p_.meshes[k].weight * EvalMesh(k, u);
  return sum;
}

}  // namespace nimbus
