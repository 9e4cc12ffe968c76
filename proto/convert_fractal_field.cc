// Converts the fractal_field generator and JobSpec.detail: meshes (explicit
// or a series), weights, interpolation, the space-to-field mapping (wind,
// periods), the output (density or terrain), the animation and the shape.
// Counts and sizes are checked before anything is built.

#include <cmath>
#include <limits>
#include <memory>

#include "core/field/field_recipe.h"
#include "proto/convert_internal.h"

namespace nimbus::spec {

namespace {

using namespace internal;  // NOLINT: converter helpers

constexpr uint32_t kMaxAnimationFrames = 4096;
// Cells below this are finer than any grid Nimbus writes (and keep period /
// cell far from integer overflow).
constexpr double kMinCell = 1e-9;
constexpr double kMaxPeriodNodes = double(int64_t{1} << 40);
// A sine wind faster than this turns 2π t / period into noise (or, for a
// subnormal period, into NaN positions and an empty volume).
constexpr double kMinSinePeriod = 1e-9;

using Repeated = google::protobuf::RepeatedField<double>;

// A per-axis list of 0, 1 (every axis) or `n` values; each checked.
absl::Status PerAxis(const Repeated& values, int n, double fallback, const std::string& path,
                     double* out) {
  if (values.size() != 0 && values.size() != 1 && values.size() != n)
    return Invalid(path, StrCat("give 1 or ", n, " values, got ", values.size()));
  for (int i = 0; i < values.size(); ++i)
    NIMBUS_RETURN_IF_ERROR(CheckNumber(values[i], StrCat(path, "[", i, "]")));
  for (int i = 0; i < n; ++i)
    out[i] = values.empty() ? fallback : values[values.size() == 1 ? 0 : i];
  return absl::OkStatus();
}

absl::Status CheckCells(const FieldVec& cell, int n, const std::string& path) {
  for (int i = 0; i < n; ++i)
    if (!(cell[i] >= kMinCell))
      return Invalid(StrCat(path, "[", i, "]"),
                     StrCat("must be >= ", kMinCell, " (a cell needs a size), got ", cell[i]));
  return absl::OkStatus();
}

absl::StatusOr<std::array<std::array<double, 3>, 3>> MeshRotation(const v1::FieldMesh& m, int s,
                                                                  const std::string& path) {
  std::array<std::array<double, 3>, 3> r{{{1, 0, 0}, {0, 1, 0}, {0, 0, 1}}};
  NIMBUS_RETURN_IF_ERROR(CheckNumber(m.rotation_degrees(), path + ".rotation_degrees"));
  if (s == 1) return Invalid(path + ".rotation_degrees", "a 1D field has nothing to rotate");
  if (s == 2) {
    const double a = m.rotation_degrees() * M_PI / 180;
    r[0] = {std::cos(a), -std::sin(a), 0};
    r[1] = {std::sin(a), std::cos(a), 0};
    return r;
  }
  if (!m.has_rotation_axis() || !Finite(m.rotation_axis()) || Length(ToVec3(m.rotation_axis())) == 0)
    return Invalid(path + ".rotation_axis", "required, finite and non-zero for a rotated 3D mesh");
  const Affine3 a = Affine3::Rotate(ToVec3(m.rotation_axis()), m.rotation_degrees());
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) r[size_t(i)][size_t(j)] = a.m[size_t(i)][size_t(j)];
  return r;
}

absl::Status ConvertExplicitMeshes(const v1::FieldSource& src, const std::string& path, int s,
                                   FractalFieldParams& p) {
  const int n = p.dims;
  for (int k = 0; k < src.meshes_size(); ++k) {
    const v1::FieldMesh& m = src.meshes(k);
    const std::string mp = StrCat(path, ".meshes[", k, "]");
    FieldMesh mesh;
    if (m.cell_size().empty()) return Invalid(mp + ".cell_size", "required");
    NIMBUS_RETURN_IF_ERROR(PerAxis(m.cell_size(), n, 0, mp + ".cell_size", mesh.cell.data()));
    NIMBUS_RETURN_IF_ERROR(CheckCells(mesh.cell, n, mp + ".cell_size"));
    NIMBUS_RETURN_IF_ERROR(PerAxis(m.offset(), n, 0, mp + ".offset", mesh.offset.data()));
    if (m.rotation_degrees() != 0) {
      auto r = MeshRotation(m, s, mp);
      if (!r.ok()) return r.status();
      mesh.rotation = *r;
      mesh.rotated = true;
    }
    p.meshes.push_back(mesh);
  }
  return absl::OkStatus();
}

absl::Status ConvertSeries(const v1::MeshSeries& ms, const std::string& path, FractalFieldParams& p) {
  if (ms.count() < 1 || ms.count() > uint32_t(kMaxFieldMeshes))
    return Invalid(path + ".count", StrCat("must be 1..", kMaxFieldMeshes, ", got ", ms.count()));
  MeshSeries series;
  series.count = int(ms.count());
  series.aligned = ms.aligned();
  if (ms.base_cell_size().empty()) return Invalid(path + ".base_cell_size", "required");
  NIMBUS_RETURN_IF_ERROR(
      PerAxis(ms.base_cell_size(), p.dims, 0, path + ".base_cell_size", series.base_cell.data()));
  NIMBUS_RETURN_IF_ERROR(CheckCells(series.base_cell, p.dims, path + ".base_cell_size"));
  series.ratio = ms.ratio() == 0 ? 0.5 : ms.ratio();
  if (!(series.ratio > 0 && series.ratio < 1))
    return Invalid(path + ".ratio", StrCat("must be in (0, 1), got ", ms.ratio()));
  p.meshes = ExpandMeshSeries(series, p.dims);
  // The finest mesh must keep a real cell size too.
  return CheckCells(p.meshes.back().cell, p.dims,
                    StrCat(path, " (mesh ", series.count - 1, ").cell_size"));
}

absl::Status ConvertMeshes(const v1::FieldSource& src, const std::string& path, int s,
                           FractalFieldParams& p) {
  if (src.meshes_size() > 0 && src.has_mesh_series())
    return Invalid(path, "set one of meshes or mesh_series, not both");
  // Counted before anything is built.
  if (src.meshes_size() > kMaxFieldMeshes)
    return Invalid(path + ".meshes",
                   StrCat("at most ", kMaxFieldMeshes, " meshes, got ", src.meshes_size()));
  if (src.has_mesh_series()) return ConvertSeries(src.mesh_series(), path + ".mesh_series", p);
  if (src.meshes_size() == 0) return Invalid(path, "set meshes or mesh_series");
  return ConvertExplicitMeshes(src, path, s, p);
}

absl::Status ConvertWeights(const v1::FieldWeights& w, const std::string& path,
                            FractalFieldParams& p) {
  WeightRule rule = WeightRule::kCellVolume;
  switch (w.rule()) {
    case v1::WEIGHT_RULE_UNSPECIFIED:
    case v1::WEIGHT_RULE_CELL_VOLUME: rule = WeightRule::kCellVolume; break;
    case v1::WEIGHT_RULE_POWER: rule = WeightRule::kPower; break;
    case v1::WEIGHT_RULE_EXPLICIT: rule = WeightRule::kExplicit; break;
    default: return Invalid(path + ".rule", StrCat("unknown value ", int(w.rule())));
  }
  if (!(w.hurst() >= -4 && w.hurst() <= 8))
    return Invalid(path + ".hurst", StrCat("must be in [-4, 8], got ", w.hurst()));
  NIMBUS_RETURN_IF_ERROR(CheckNumber(w.amplitude(), path + ".amplitude"));
  if (rule != WeightRule::kExplicit && w.explicit_weights_size() > 0)
    return Invalid(path + ".explicit_weights", "only with WEIGHT_RULE_EXPLICIT");
  std::vector<double> explicit_weights;
  for (int i = 0; i < w.explicit_weights_size(); ++i) {
    const double v = w.explicit_weights(i);
    if (!std::isfinite(v))
      return Invalid(StrCat(path, ".explicit_weights[", i, "]"), StrCat("must be finite, got ", v));
    NIMBUS_RETURN_IF_ERROR(CheckNumber(v, StrCat(path, ".explicit_weights[", i, "]")));
    explicit_weights.push_back(v);
  }
  const double amplitude = w.amplitude() == 0 ? 1.0 : w.amplitude();
  if (rule != WeightRule::kExplicit && std::abs(amplitude) < std::numeric_limits<double>::min())
    return Invalid(path + ".amplitude", StrCat("too close to 0 to weigh anything, got ", amplitude));
  absl::Status st = ApplyWeightRule(rule, amplitude, w.hurst(), explicit_weights, p.dims, p.meshes);
  if (!st.ok()) return Invalid(path, std::string(st.message()));
  // The field is divided by Σ|weight|: with none, every voxel is empty.
  double sum = 0;
  for (const FieldMesh& m : p.meshes) sum += std::abs(m.weight);
  if (rule == WeightRule::kExplicit && !(sum >= std::numeric_limits<double>::min()))
    return Invalid(path + ".explicit_weights", "need at least one weight that is not 0");
  return absl::OkStatus();
}

absl::Status ConvertInterpolation(v1::FieldInterpolation i, const std::string& path,
                                  FieldInterpolation& out) {
  switch (i) {
    case v1::FIELD_INTERPOLATION_UNSPECIFIED:
    case v1::FIELD_INTERPOLATION_LINEAR: out = FieldInterpolation::kLinear; return absl::OkStatus();
    case v1::FIELD_INTERPOLATION_PSEUDO_CUBIC:
      out = FieldInterpolation::kPseudoCubic;
      return absl::OkStatus();
    case v1::FIELD_INTERPOLATION_QUINTIC: out = FieldInterpolation::kQuintic; return absl::OkStatus();
    case v1::FIELD_INTERPOLATION_CUBIC: out = FieldInterpolation::kCubic; return absl::OkStatus();
    default: return Invalid(path, StrCat("unknown value ", int(i)));
  }
}

absl::Status ConvertWind(const v1::FieldWind& w, const std::string& path, int s, Wind& out) {
  switch (w.kind()) {
    case v1::WIND_KIND_UNSPECIFIED:
    case v1::WIND_KIND_NONE: out.kind = WindKind::kNone; break;
    case v1::WIND_KIND_LINEAR: out.kind = WindKind::kLinear; break;
    case v1::WIND_KIND_SINE: out.kind = WindKind::kSine; break;
    default: return Invalid(path + ".kind", StrCat("unknown value ", int(w.kind())));
  }
  if (w.velocity_size() > s) return Invalid(path + ".velocity", StrCat("at most ", s, " values"));
  if (w.amplitude_size() > s) return Invalid(path + ".amplitude", StrCat("at most ", s, " values"));
  for (int i = 0; i < w.velocity_size(); ++i) {
    NIMBUS_RETURN_IF_ERROR(CheckNumber(w.velocity(i), StrCat(path, ".velocity[", i, "]")));
    out.velocity[size_t(i)] = w.velocity(i);
  }
  for (int i = 0; i < w.amplitude_size(); ++i) {
    NIMBUS_RETURN_IF_ERROR(CheckNumber(w.amplitude(i), StrCat(path, ".amplitude[", i, "]")));
    out.amplitude[size_t(i)] = w.amplitude(i);
  }
  out.sine_period = w.period() == 0 ? 1.0 : w.period();
  if (!(out.sine_period >= kMinSinePeriod && out.sine_period <= kMaxMagnitude))
    return Invalid(path + ".period", StrCat("must be in [", kMinSinePeriod, ", ", kMaxMagnitude,
                                            "] time units (0: 1), got ", w.period()));
  NIMBUS_RETURN_IF_ERROR(CheckNumber(w.phase_degrees(), path + ".phase_degrees"));
  out.phase_radians = w.phase_degrees() * M_PI / 180;
  return absl::OkStatus();
}

absl::Status ConvertMapping(const v1::FieldMapping& m, const std::string& path, int s,
                            FieldMapping& out) {
  out.space_dims = s;
  if (m.scale_size() > 0 && m.matrix_size() > 0)
    return Invalid(path, "set one of scale or matrix, not both");
  if (m.matrix_size() > 0) {
    if (m.matrix_size() != s * s)
      return Invalid(path + ".matrix", StrCat("needs ", s * s, " values, got ", m.matrix_size()));
    for (int i = 0; i < s * s; ++i) {
      NIMBUS_RETURN_IF_ERROR(CheckNumber(m.matrix(i), StrCat(path, ".matrix[", i, "]")));
      out.matrix[size_t(i / s)][size_t(i % s)] = m.matrix(i);
    }
  } else {
    double scale[3] = {1, 1, 1};
    NIMBUS_RETURN_IF_ERROR(PerAxis(m.scale(), s, 1, path + ".scale", scale));
    for (int i = 0; i < s; ++i) out.matrix[size_t(i)][size_t(i)] = scale[i];
  }
  if (m.offset_size() > s) return Invalid(path + ".offset", StrCat("at most ", s, " values"));
  for (int i = 0; i < m.offset_size(); ++i) {
    NIMBUS_RETURN_IF_ERROR(CheckNumber(m.offset(i), StrCat(path, ".offset[", i, "]")));
    out.offset[size_t(i)] = m.offset(i);
  }
  NIMBUS_RETURN_IF_ERROR(ConvertWind(m.wind(), path + ".wind", s, out.wind));
  return absl::OkStatus();
}

absl::Status ConvertPeriods(const v1::FieldMapping& m, const std::string& path,
                            FractalFieldParams& p) {
  if (m.period_size() > p.dims)
    return Invalid(path + ".period", StrCat("at most ", p.dims, " values (one per field axis)"));
  for (int i = 0; i < m.period_size(); ++i) {
    const std::string f = StrCat(path, ".period[", i, "]");
    NIMBUS_RETURN_IF_ERROR(CheckNumber(m.period(i), f));
    if (m.period(i) != 0 && !(m.period(i) >= kMinCell))
      return Invalid(f, StrCat("must be 0 (not periodic) or >= ", kMinCell, ", got ", m.period(i)));
    p.mapping.period[size_t(i)] = m.period(i);
  }
  return absl::OkStatus();
}

// Periods need whole cells, within integer range; rotated meshes cannot
// repeat along the lattice axes.
absl::Status CheckPeriods(const FractalFieldParams& p, const std::string& path) {
  for (int i = 0; i < p.dims; ++i) {
    if (!(p.mapping.period[i] > 0)) continue;
    for (size_t k = 0; k < p.meshes.size(); ++k) {
      if (p.meshes[k].rotated && i < p.mapping.space_dims)
        return Invalid(StrCat(path, ".meshes[", k, "].rotation_degrees"),
                       StrCat("a rotated mesh cannot repeat along axis ", i,
                              " (mapping.period is set)"));
      if (p.mapping.period[i] / p.meshes[k].cell[i] > kMaxPeriodNodes)
        return Invalid(StrCat(path, ".mapping.period[", i, "]"),
                       StrCat("holds more than 2^40 cells of mesh ", k));
    }
  }
  return absl::OkStatus();
}

}  // namespace

namespace internal {

// The field part shared by fractal_field.field and detail.field. `s` is
// the number of spatial axes; `time_axis` allows n = s + 1.
absl::Status ConvertFieldSource(const v1::FieldSource& src, const std::string& path, int s,
                                bool time_axis, const std::string& purpose,
                                FractalFieldParams& p) {
  const uint32_t n = src.dimensions();
  if (n < 1 || n > uint32_t(kMaxFieldDims))
    return Invalid(path + ".dimensions", StrCat("must be 1..4, got ", n));
  if (!(int(n) == s || (time_axis && int(n) == s + 1)))
    return Invalid(path + ".dimensions",
                   StrCat(purpose, " needs ", s, time_axis ? StrCat(" (or ", s + 1, " with time)") : "",
                          " dimensions, got ", n));
  p.dims = int(n);
  p.seed = src.seed();
  NIMBUS_RETURN_IF_ERROR(ConvertMeshes(src, path, s, p));
  NIMBUS_RETURN_IF_ERROR(ConvertWeights(src.weights(), path + ".weights", p));
  NIMBUS_RETURN_IF_ERROR(ConvertInterpolation(src.interpolation(), path + ".interpolation",
                                              p.interpolation));
  NIMBUS_RETURN_IF_ERROR(ConvertMapping(src.mapping(), path + ".mapping", s, p.mapping));
  return ConvertPeriods(src.mapping(), path + ".mapping", p);
}

// Snaps cells to the periods, then the engine's own check (defensive: the
// converter has refused everything it can name more precisely).
absl::Status FinishField(const std::string& path, JobPlan& job, FractalFieldParams& p) {
  NIMBUS_RETURN_IF_ERROR(CheckPeriods(p, path));
  std::vector<std::string> notes;
  SnapCellsToPeriods(p, &notes);
  for (std::string& note : notes) job.warnings.push_back(StrCat(path, ".", note));
  if (absl::Status st = ValidateFieldParams(p); !st.ok())
    return Invalid(path, std::string(st.message()));
  return absl::OkStatus();
}

}  // namespace internal

namespace {

// A loop must return the field to itself after frames * time_step: the
// time axis gets that period, and the wind must move by whole periods.
absl::Status ConvertLoop(const FieldAnimation& a, const std::string& path, FractalFieldParams& p) {
  const double span = double(a.frames) * a.time_step;
  const int s = p.mapping.space_dims;
  if (p.dims > s) {
    const double given = p.mapping.period[size_t(s)];
    if (given > 0 && std::abs(given - span) > 1e-9 * span)
      return Invalid(StrCat(path, ".field.mapping.period[", s, "]"),
                     StrCat("a loop sets the time period to frames * time_step = ", span,
                            "; got ", given));
    p.mapping.period[size_t(s)] = span;
  }
  const Wind& w = p.mapping.wind;
  auto whole = [](double q) { return std::abs(q - std::round(q)) <= 1e-9 * std::max(1.0, std::abs(q)); };
  if (w.kind == WindKind::kSine && !whole(span / w.sine_period))
    return Invalid(path + ".field.mapping.wind.period",
                   StrCat("a loop of ", span, " time units needs a whole number of sine periods"));
  for (int i = 0; i < s; ++i) {
    const double shift = w.kind == WindKind::kLinear ? w.velocity[size_t(i)] * span : 0.0;
    if (shift == 0) continue;
    const double period = p.mapping.period[size_t(i)];
    if (!(period > 0))
      return Invalid(StrCat(path, ".field.mapping.period[", i, "]"),
                     "a looping wind needs this axis to be periodic");
    if (!whole(shift / period))
      return Invalid(StrCat(path, ".field.mapping.wind.velocity[", i, "]"),
                     StrCat("moves the field ", shift, " per loop, not a whole number of periods (",
                            period, ")"));
  }
  return absl::OkStatus();
}

absl::Status ConvertAnimation(const v1::FieldAnimation& a, const std::string& path,
                              FieldAnimation& out) {
  if (a.frames() > kMaxAnimationFrames)
    return Invalid(path + ".frames",
                   StrCat("at most ", kMaxAnimationFrames, " frames, got ", a.frames()));
  out.frames = a.frames();
  NIMBUS_RETURN_IF_ERROR(CheckNumber(a.time_start(), path + ".time_start"));
  out.time_start = a.time_start();
  out.time_step = a.time_step() == 0 ? 1.0 : a.time_step();
  if (!(std::isfinite(out.time_step) && out.time_step > 0 && out.time_step <= kMaxMagnitude))
    return Invalid(path + ".time_step", StrCat("must be finite and > 0, got ", a.time_step()));
  out.loop = a.loop();
  if (out.loop && out.frames < 1) return Invalid(path + ".loop", "needs frames >= 1");
  return absl::OkStatus();
}

absl::Status ConvertOutputs(const v1::FractalField& f, const GridFrame& frame,
                            FractalFieldPlan& plan) {
  if (f.has_density() && f.has_terrain())
    return Invalid("fractal_field", "set at most one of density and terrain");
  plan.output = f.has_terrain() ? FieldOutputKind::kTerrain : FieldOutputKind::kDensity;
  const v1::FieldDensity& d = f.density();
  NIMBUS_RETURN_IF_ERROR(CheckNumber(d.threshold(), "fractal_field.density.threshold"));
  plan.density.threshold = d.threshold();
  // Without a shape v lies in [-1, 1]: from 1 up, every voxel is empty.
  if (plan.output == FieldOutputKind::kDensity && !f.has_shape() && d.threshold() >= 1)
    return Invalid("fractal_field.density.threshold",
                   StrCat("must be < 1 without a shape (the field lies in [-1, 1], so every "
                          "voxel would be empty), got ", d.threshold()));
  plan.density.gain = d.gain() == 0 ? 1.0 : d.gain();
  if (!(plan.density.gain > 0 && plan.density.gain <= kMaxMagnitude))
    return Invalid("fractal_field.density.gain", StrCat("must be finite and > 0, got ", d.gain()));
  // Densities are floats: a smaller gain rounds every one to 0.
  if (plan.density.gain < std::numeric_limits<float>::min())
    return Invalid("fractal_field.density.gain",
                   StrCat("must be at least ", std::numeric_limits<float>::min(),
                          " (smaller densities round to 0), got ", d.gain()));
  plan.density.soft_clip = d.soft_clip();
  const v1::FieldTerrain& t = f.terrain();
  const double z0 = frame.bounds.min.z, z1 = frame.bounds.max.z;
  if (t.has_base_height())
    NIMBUS_RETURN_IF_ERROR(CheckNumber(t.base_height(), "fractal_field.terrain.base_height"));
  plan.terrain.base_height = t.has_base_height() ? t.base_height() : (z0 + z1) / 2;
  NIMBUS_RETURN_IF_ERROR(CheckNumber(t.height_scale(), "fractal_field.terrain.height_scale"));
  plan.terrain.height_scale = t.height_scale() == 0 ? (z1 - z0) / 4 : t.height_scale();
  plan.terrain.png = !t.no_png();
  return absl::OkStatus();
}

absl::Status ConvertShape(const v1::FieldShape& sh, const Limits& limits, JobPlan& job,
                          FractalFieldPlan& plan) {
  const std::string path = "fractal_field.shape";
  if (plan.output != FieldOutputKind::kDensity)
    return Invalid(path, "a shape needs the density output, not a terrain");
  const Int3 r = job.frame.resolution;
  for (int a = 0; a < 3; ++a)
    if (r[a] > VoxelSet::kMaxResolution)
      return absl::ResourceExhaustedError(StrCat("grid.resolution[", a, "]: shaped fields allow at most ",
                                                 VoxelSet::kMaxResolution, " voxels per axis"));
  if (!sh.has_source()) return Invalid(path + ".source", "required");
  FieldShapePlan shape;
  NIMBUS_RETURN_IF_ERROR(ConvertSetSource(sh.source(), path + ".source", limits, job, shape.source));
  const Vec3 h = job.frame.VoxelSize();
  shape.falloff = sh.falloff() == 0 ? 4 * std::max({h.x, h.y, h.z}) : sh.falloff();
  if (!(shape.falloff > 0 && shape.falloff <= kMaxMagnitude))
    return Invalid(path + ".falloff", StrCat("must be finite and > 0, got ", sh.falloff()));
  NIMBUS_RETURN_IF_ERROR(CheckNumber(sh.detail(), path + ".detail"));
  shape.detail = sh.detail() == 0 ? 0.5 : sh.detail();
  plan.shape = std::move(shape);
  return absl::OkStatus();
}

}  // namespace

namespace internal {

absl::Status ConvertFractalField(const v1::FractalField& f, const Limits& limits, JobPlan& job) {
  FractalFieldPlan plan;
  NIMBUS_RETURN_IF_ERROR(ConvertOutputs(f, job.frame, plan));
  const bool terrain = plan.output == FieldOutputKind::kTerrain;
  if (!f.has_field()) return Invalid("fractal_field.field", "required");
  NIMBUS_RETURN_IF_ERROR(ConvertFieldSource(f.field(), "fractal_field.field", terrain ? 2 : 3, true,
                                            terrain ? "a terrain" : "a density volume",
                                            plan.field));
  NIMBUS_RETURN_IF_ERROR(ConvertAnimation(f.animation(), "fractal_field.animation", plan.animation));
  if (plan.animation.loop)
    NIMBUS_RETURN_IF_ERROR(ConvertLoop(plan.animation, "fractal_field", plan.field));
  NIMBUS_RETURN_IF_ERROR(FinishField("fractal_field.field", job, plan.field));
  if (f.has_shape()) NIMBUS_RETURN_IF_ERROR(ConvertShape(f.shape(), limits, job, plan));
  job.work = {uint64_t(std::max<int64_t>(plan.animation.frames, 1)), "frames"};
  job.kind = std::move(plan);
  return absl::OkStatus();
}

absl::Status ConvertFieldDetail(const v1::FieldDetail& d, JobPlan& job) {
  if (!d.has_field()) return Invalid("detail.field", "required");
  FractalFieldParams p;
  NIMBUS_RETURN_IF_ERROR(
      ConvertFieldSource(d.field(), "detail.field", 3, false, "detail on a volume", p));
  NIMBUS_RETURN_IF_ERROR(FinishField("detail.field", job, p));
  NIMBUS_RETURN_IF_ERROR(CheckNumber(d.strength(), "detail.strength"));
  const double strength = d.strength() == 0 ? 1.0 : d.strength();
  auto field = std::make_shared<const FractalField>(std::move(p));
  const double w = field->WeightSum();
  job.density.modulation = [field, strength, w](const Vec3& at) {
    const double x[3] = {at.x, at.y, at.z};
    return 1 + strength * (w > 0 ? field->Sample(x, 0) / w : 0.0);
  };
  return absl::OkStatus();
}

}  // namespace internal

}  // namespace nimbus::spec
