#include "proto/spec_convert.h"

#include <cmath>

#include "absl/strings/str_join.h"
#include "core/base/sha256.h"
#include "proto/convert_internal.h"
#include "proto/spec_shape.h"

namespace nimbus::spec {

namespace internal {


absl::Status Invalid(const std::string& path, const std::string& what) {
  return absl::InvalidArgumentError(StrCat(path, ": ", what));
}

bool InRange(double x) { return std::isfinite(x) && std::abs(x) <= kMaxMagnitude; }

absl::Status CheckNumber(double x, const std::string& path) {
  if (InRange(x)) return absl::OkStatus();
  return Invalid(path, StrCat("must be finite and within ±1e12, got ", x));
}

bool Finite(const v1::Vec3& v) { return InRange(v.x()) && InRange(v.y()) && InRange(v.z()); }

absl::Status CheckProbabilityMode(v1::ProbabilityMode mode, const std::string& path) {
  switch (mode) {
    case v1::PROBABILITY_MODE_UNSPECIFIED:
    case v1::PROBABILITY_MODE_EXPLICIT:
    case v1::PROBABILITY_MODE_DETERMINANT:
      return absl::OkStatus();
    default:
      return Invalid(path, StrCat("unknown value ", int(mode),
                                  " (known: PROBABILITY_MODE_EXPLICIT, "
                                  "PROBABILITY_MODE_DETERMINANT)"));
  }
}
Vec3 ToVec3(const v1::Vec3& v) { return {v.x(), v.y(), v.z()}; }

}  // namespace internal

namespace {

using namespace internal;  // NOLINT: converter helpers

absl::StatusOr<Affine3> ConvertStep(const v1::Step& s, const std::string& path) {
  switch (s.kind_case()) {
    case v1::Step::kTranslate:
      if (!Finite(s.translate()))
        return Invalid(path + ".translate", "must be finite and within ±1e12");
      return Affine3::Translate(ToVec3(s.translate()));
    case v1::Step::kRotate: {
      const Vec3 axis = ToVec3(s.rotate().axis());
      if (!Finite(s.rotate().axis()) || !InRange(s.rotate().degrees()))
        return Invalid(path + ".rotate", "axis and degrees must be finite and within ±1e12");
      if (Length(axis) == 0) return Invalid(path + ".rotate.axis", "must not be zero");
      return Affine3::Rotate(axis, s.rotate().degrees());
    }
    case v1::Step::kScale: {
      const v1::Scale& sc = s.scale();
      if (sc.has_xyz() == (sc.uniform() != 0))
        return Invalid(path + ".scale", "set exactly one of uniform or xyz");
      if (sc.has_xyz()) {
        if (!Finite(sc.xyz()))
          return Invalid(path + ".scale.xyz", "must be finite and within ±1e12");
        return Affine3::Scale(ToVec3(sc.xyz()));
      }
      NIMBUS_RETURN_IF_ERROR(CheckNumber(sc.uniform(), path + ".scale.uniform"));
      return Affine3::Scale({sc.uniform(), sc.uniform(), sc.uniform()});
    }
    case v1::Step::kShear: {
      const v1::Shear& h = s.shear();
      for (double v : {h.xy(), h.xz(), h.yx(), h.yz(), h.zx(), h.zy()})
        if (!InRange(v)) return Invalid(path + ".shear", "must be finite and within ±1e12");
      return Affine3::Shear(h.xy(), h.xz(), h.yx(), h.yz(), h.zx(), h.zy());
    }
    case v1::Step::kMatrix: {
      const auto& v = s.matrix().values();
      if (v.size() != 12)
        return Invalid(path + ".matrix.values",
                       StrCat("needs 12 numbers (3 rows of 4, row-major), got ", v.size()));
      Affine3 a;
      for (int i = 0; i < 12; ++i) {
        NIMBUS_RETURN_IF_ERROR(CheckNumber(v[i], StrCat(path, ".matrix.values[", i, "]")));
        a.m[i / 4][i % 4] = v[i];
      }
      return a;
    }
    case v1::Step::KIND_NOT_SET:
      break;
  }
  return Invalid(path, "empty step: set one of translate, rotate, scale, shear, matrix");
}

absl::StatusOr<GridFrame> ConvertGrid(const v1::JobSpec& spec, const Limits& limits) {
  if (!spec.has_grid()) return Invalid("grid", "required");
  const v1::Grid& g = spec.grid();
  GridFrame f;
  const auto& r = g.resolution();
  if (r.size() != 1 && r.size() != 3)
    return Invalid("grid.resolution", StrCat("give 1 or 3 values, got ", r.size()));
  for (int i = 0; i < r.size(); ++i) {
    if (r[i] <= 0)
      return Invalid(StrCat("grid.resolution[", i, "]"), StrCat("must be positive, got ", r[i]));
    if (r[i] > limits.max_resolution)
      return absl::ResourceExhaustedError(
          StrCat("grid.resolution[", i, "]: ", r[i], " exceeds the server limit of ",
                 limits.max_resolution, " voxels per axis"));
  }
  f.resolution = r.size() == 1 ? Int3{r[0], r[0], r[0]} : Int3{r[0], r[1], r[2]};
  if (f.resolution.Volume() > limits.max_voxels)
    return absl::ResourceExhaustedError(StrCat("grid.resolution: ", f.resolution.Volume(),
                                               " voxels exceed the server limit of ",
                                               limits.max_voxels));
  if (!g.has_bounds_min() && !g.has_bounds_max()) {
    f.bounds = {{-1, -1, -1}, {1, 1, 1}};
  } else {
    // Each bound by name; the width must stay finite too (±1e12 keeps it).
    NIMBUS_RETURN_IF_ERROR(CheckNumber(g.bounds_min().x(), "grid.bounds_min.x"));
    NIMBUS_RETURN_IF_ERROR(CheckNumber(g.bounds_min().y(), "grid.bounds_min.y"));
    NIMBUS_RETURN_IF_ERROR(CheckNumber(g.bounds_min().z(), "grid.bounds_min.z"));
    NIMBUS_RETURN_IF_ERROR(CheckNumber(g.bounds_max().x(), "grid.bounds_max.x"));
    NIMBUS_RETURN_IF_ERROR(CheckNumber(g.bounds_max().y(), "grid.bounds_max.y"));
    NIMBUS_RETURN_IF_ERROR(CheckNumber(g.bounds_max().z(), "grid.bounds_max.z"));
    f.bounds = {ToVec3(g.bounds_min()), ToVec3(g.bounds_max())};
    static const char* kAxis[3] = {"x", "y", "z"};
    for (int a = 0; a < 3; ++a)
      if (!(f.bounds.max[a] > f.bounds.min[a]))
        return Invalid(StrCat("grid.bounds_max.", kAxis[a]),
                       StrCat("must be greater than grid.bounds_min.", kAxis[a]));
  }
  return f;
}

}  // namespace

using namespace internal;  // NOLINT

absl::StatusOr<Affine3> ComposeSteps(const google::protobuf::RepeatedPtrField<v1::Step>& steps,
                                     const std::string& path) {
  Affine3 a;
  // Right to left: the last step acts first, so compose left to right.
  for (int i = 0; i < steps.size(); ++i) {
    auto s = ConvertStep(steps[i], StrCat(path, "[", i, "]"));
    if (!s.ok()) return s.status();
    a = a * *s;
  }
  return a;
}

namespace {

// Names go into file names, grid names, logs and every listing: short, and
// letters, digits, '_', '-' and '.' only.
absl::Status CheckPlainName(const std::string& name, const std::string& field) {
  if (name.size() > 128)
    return Invalid(field, StrCat("must be at most 128 bytes, got ", name.size()));
  for (char c : name)
    if (!(std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '-' || c == '.'))
      return Invalid(field, "use letters, digits, '_', '-' and '.' only");
  return absl::OkStatus();
}

absl::Status ConvertName(const v1::JobSpec& spec, JobPlan& job) {
  NIMBUS_RETURN_IF_ERROR(CheckPlainName(spec.name(), "name"));
  job.name = spec.name().empty() ? "nimbus" : spec.name();
  return absl::OkStatus();
}

// The density grid's name: a plain name that no other grid of the file has.
absl::Status CheckGridName(const std::string& name) {
  NIMBUS_RETURN_IF_ERROR(CheckPlainName(name, "output.grid_name"));
  for (const char* taken : {"Cd", "address", "counts", "component", "v"})
    if (name == taken)
      return Invalid("output.grid_name",
                     StrCat("'", name, "' is the name of another grid Nimbus may write"));
  return absl::OkStatus();
}

// 0 (off) or within [lo, hi]: a limit below lo leaves nothing worth
// writing, one above hi is a typo, not a wish.
absl::Status CheckLimit(int64_t v, int64_t lo, int64_t hi, const std::string& path) {
  if (v == 0 || (v >= lo && v <= hi)) return absl::OkStatus();
  return Invalid(path, StrCat("must be 0 (no limit) or in [", lo, ", ", hi, "], got ", v));
}

// Up axis, half floats and the downsampling limits (docs/dcc.md).
absl::Status ConvertConventions(const v1::Output& o, OutputConventions& c) {
  switch (o.up_axis()) {
    case v1::UP_AXIS_UNSPECIFIED:
    case v1::UP_AXIS_Y: c.up_axis = UpAxis::kY; break;
    case v1::UP_AXIS_Z: c.up_axis = UpAxis::kZ; break;
    default:
      return Invalid("output.up_axis",
                     StrCat("unknown value ", int(o.up_axis()), " (known: UP_AXIS_Y, UP_AXIS_Z)"));
  }
  c.half_float = o.half_float();
  NIMBUS_RETURN_IF_ERROR(
      CheckLimit(o.max_voxels(), kMinOutputVoxels, kMaxOutputVoxels, "output.max_voxels"));
  NIMBUS_RETURN_IF_ERROR(CheckLimit(o.target_file_bytes(), kMinTargetFileBytes,
                                    kMaxTargetFileBytes, "output.target_file_bytes"));
  c.max_voxels = o.max_voxels();
  c.target_file_bytes = o.target_file_bytes();
  return absl::OkStatus();
}

absl::Status ConvertOutput(const v1::Output& o, DensityOptions& density) {
  NIMBUS_RETURN_IF_ERROR(CheckGridName(o.grid_name()));
  density.grid_name = o.grid_name().empty() ? "density" : o.grid_name();
  switch (o.density_mapping()) {
    case v1::DENSITY_MAPPING_UNSPECIFIED:
    case v1::DENSITY_MAPPING_LINEAR: density.mapping = DensityMapping::kLinear; break;
    case v1::DENSITY_MAPPING_SQRT: density.mapping = DensityMapping::kSqrt; break;
    case v1::DENSITY_MAPPING_LOG: density.mapping = DensityMapping::kLog; break;
    case v1::DENSITY_MAPPING_GAMMA: density.mapping = DensityMapping::kGamma; break;
    default:
      return Invalid("output.density_mapping",
                     StrCat("unknown value ", int(o.density_mapping())));
  }
  // 0 means the default; beyond 1000 every density maps to 0 or 1.
  if (!(o.gamma() >= 0 && o.gamma() <= 1000))
    return Invalid("output.gamma", StrCat("must be in (0, 1000], got ", o.gamma()));
  density.gamma = o.gamma() == 0 ? 2.2 : o.gamma();
  return ConvertConventions(o, density.conventions);
}

// The output field that asked for downsampling, for errors.
const char* DownsamplingField(const v1::Output& o) {
  return o.max_voxels() != 0 ? "output.max_voxels" : "output.target_file_bytes";
}

// Sharding (docs/sharding.md) once the kind is known: one chaos game that
// runs to its end, and no more shards than chunks.
absl::Status CheckShards(const v1::JobSpec& spec, const JobPlan& job) {
  const uint32_t s = spec.shards();
  if (s <= 1) return absl::OkStatus();
  if (s > kMaxShards) return Invalid("shards", StrCat("must be at most ", kMaxShards, ", got ", s));
  const ChaosGameParams* run = job.shardable_run();
  if (run == nullptr) {
    if (spec.has_image()) return Invalid("shards", "cannot be combined with image");
    if (spec.grid().has_auto_frame())
      return Invalid("shards", "cannot be combined with grid.auto_frame");
    if (job.ifs_matrix())
      return Invalid("shards", "cannot be combined with chaos_game.matrices.component_grid");
    return Invalid("shards", StrCat("applies to chaos_game jobs only, not ",
                                    std::string(KindName(job.kind))));
  }
  if (run->convergence.tolerance > 0)
    return Invalid("shards", "cannot be combined with chaos_game.convergence: where it stops "
                             "depends on the whole run");
  const uint64_t chunks = ChaosGame::NumChunks(run->iterations);
  if (s > chunks)
    return Invalid("shards", StrCat("must be at most the run's ", chunks,
                                    " chunks of 2^20 iterations, got ", s));
  return absl::OkStatus();
}

}  // namespace

absl::StatusOr<JobPlan> ConvertSpec(const v1::JobSpec& spec, const Limits& limits) {
  NIMBUS_RETURN_IF_ERROR(CheckSpecShape(spec, limits));
  JobPlan job;
  NIMBUS_RETURN_IF_ERROR(ConvertName(spec, job));
  // An exploration frames each candidate itself: its grid is optional.
  if (spec.has_explore() && !spec.has_grid()) {
    job.frame = {{1, 1, 1}, {{-1, -1, -1}, {1, 1, 1}}};
  } else {
    NIMBUS_ASSIGN_OR_RETURN(job.frame, ConvertGrid(spec, limits));
  }
  // Every kind's converter sees the output options (colour adds to them).
  NIMBUS_RETURN_IF_ERROR(ConvertOutput(spec.output(), job.density));
  // The job-kind seam: one converter per generator of the spec's oneof.
  switch (spec.generator_case()) {
    case v1::JobSpec::kChaosGame:
      NIMBUS_RETURN_IF_ERROR(ConvertChaosGame(spec.chaos_game(), limits, job));
      break;
    case v1::JobSpec::kSetIfs:
      NIMBUS_RETURN_IF_ERROR(ConvertSetIfs(spec.set_ifs(), limits, job));
      break;
    case v1::JobSpec::kFractalField:
      NIMBUS_RETURN_IF_ERROR(ConvertFractalField(spec.fractal_field(), limits, job));
      // Field volumes are computed at the grid's resolution: ask for fewer voxels there.
      if (job.density.conventions.Downsamples())
        return Invalid(DownsamplingField(spec.output()),
                       "fractal_field jobs are not downsampled; lower grid.resolution instead");
      break;
    case v1::JobSpec::kJelly:
      NIMBUS_RETURN_IF_ERROR(ConvertJelly(spec.jelly(), limits, job));
      // The velocity grid is not coarsened: its voxels stay the density's.
      if (job.density.conventions.Downsamples() && !spec.jelly().no_velocity_grid())
        return Invalid(DownsamplingField(spec.output()),
                       "jelly frames with a velocity grid are not downsampled; set "
                       "jelly.no_velocity_grid or lower grid.resolution");
      break;
    case v1::JobSpec::kExplore:
      NIMBUS_RETURN_IF_ERROR(ConvertExplore(spec.explore(), limits, job));
      if (spec.has_detail()) return Invalid("detail", "does not apply to explore jobs");
      break;
    case v1::JobSpec::GENERATOR_NOT_SET:
      return Invalid("generator",
                     "set one of: chaos_game, set_ifs, fractal_field, jelly, explore");
  }
  if (spec.has_detail()) NIMBUS_RETURN_IF_ERROR(ConvertFieldDetail(spec.detail(), job));
  NIMBUS_RETURN_IF_ERROR(CheckShards(spec, job));
  NIMBUS_RETURN_IF_ERROR(ConvertImage(spec, job));
  NIMBUS_RETURN_IF_ERROR(ConvertAutoFrame(spec, job));
  return job;
}

std::string SpecHash(const v1::JobSpec& spec_in) {
  const v1::JobSpec* canonical = &spec_in;
  v1::JobSpec stripped;
  if (spec_in.shards() != 0 || spec_in.no_cache()) {
    stripped = spec_in;
    stripped.clear_shards();
    stripped.clear_no_cache();
    canonical = &stripped;
  }
  const v1::JobSpec& spec = *canonical;
  std::string bytes;
  google::protobuf::io::StringOutputStream sos(&bytes);
  google::protobuf::io::CodedOutputStream cos(&sos);
  cos.SetSerializationDeterministic(true);
  spec.SerializeToCodedStream(&cos);
  cos.Trim();
  return Sha256Hex(bytes);
}

}  // namespace nimbus::spec
