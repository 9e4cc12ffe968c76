// Converts the set_ifs generator: set sources (assets, shapes), set maps,
// probabilities, and the random iteration or book budget.

#include <cmath>

#include "absl/strings/str_join.h"
#include "core/sets/set_ifs.h"
#include "core/sets/set_ifs_plan.h"
#include "core/sets/voxelize.h"
#include "google/protobuf/io/coded_stream.h"
#include "google/protobuf/io/zero_copy_stream_impl_lite.h"
#include "proto/asset_paths.h"
#include "proto/convert_internal.h"

namespace nimbus::spec {

namespace {

using namespace internal;  // NOLINT: converter helpers

constexpr int kMaxSourceDepth = 8;
constexpr uint64_t kMaxBookPages = 4096;
// Text a spec hands us that ends up in messages, warnings and logs.
constexpr size_t kMaxLabelBytes = 255;
constexpr size_t kMaxPathBytes = 4096;
constexpr size_t kMaxGridNameBytes = 256;

absl::Status CheckLength(const std::string& value, size_t max, const std::string& field) {
  if (value.size() <= max) return absl::OkStatus();
  return Invalid(field, StrCat("must be at most ", max, " bytes, got ", value.size()));
}

std::string Deterministic(const google::protobuf::Message& m) {
  std::string bytes;
  google::protobuf::io::StringOutputStream sos(&bytes);
  google::protobuf::io::CodedOutputStream cos(&sos);
  cos.SetSerializationDeterministic(true);
  m.SerializeToCodedStream(&cos);
  cos.Trim();
  return bytes;
}

bool IsHexSha256(const std::string& s) {
  if (s.size() != 64) return false;
  for (char c : s)
    if (!((c >= '0' && c <= '9') || (c >= 'a' && c <= 'f'))) return false;
  return true;
}

// Resolves an Asset to a readable local file.
absl::Status ResolveAsset(const v1::Asset& asset, const std::string& field, const Limits& limits,
                          SetSourcePlan& out) {
  if (auto st = CheckLength(asset.label(), kMaxLabelBytes, field + ".label"); !st.ok()) return st;
  switch (asset.source_case()) {
    case v1::Asset::kSha256: {
      if (!IsHexSha256(asset.sha256()))
        return Invalid(field + ".sha256", "must be 64 lower-case hex digits");
      if (limits.asset_dir.empty())
        return Invalid(field + ".sha256", "this server has no asset store");
      auto stored = FindStoredAssetInfo(limits.asset_dir, asset.sha256());
      if (!stored.ok())
        return Invalid(field + ".sha256",
                       StrCat("no uploaded asset ", asset.sha256(), " (upload it first)"));
      out.file = stored->path;
      // Stored by content: the spec's label, or an upload's name, gives the
      // format; messages name the artist's file, never a server path.
      out.file_format = AssetFormat(asset.label(), *stored);
      out.file_label = AssetDisplayName(asset.label(), asset.sha256());
      return absl::OkStatus();
    }
    case v1::Asset::kPath: {
      if (!limits.allow_local_paths) return LocalPathRefused(field);
      if (auto st = CheckLength(asset.path(), kMaxPathBytes, field + ".path"); !st.ok()) return st;
      if (asset.path().empty()) return Invalid(field + ".path", "must not be empty");
      std::error_code ec;
      if (!std::filesystem::is_regular_file(asset.path(), ec))
        return Invalid(field + ".path", StrCat("no such file: ", asset.path()));
      out.file = asset.path();
      out.file_label = asset.path();
      out.file_format = KnownAssetFormat(asset.label());
      return absl::OkStatus();
    }
    case v1::Asset::SOURCE_NOT_SET:
      break;
  }
  return Invalid(field, "required: set sha256 or path");
}

absl::Status CheckPositive(double v, const std::string& field) {
  if (!(std::isfinite(v) && v > 0)) return Invalid(field, "must be a finite number > 0");
  return absl::OkStatus();
}

absl::Status ConvertSource(const v1::SetSource& s, const std::string& field, const Limits& limits,
                           int depth, JobPlan& job, SetSourcePlan& out) {
  if (depth > kMaxSourceDepth) return Invalid(field, "sources nest too deeply");
  out.field = field;
  out.cache_key = Deterministic(s);
  switch (s.kind_case()) {
    case v1::SetSource::kMesh: {
      const v1::MeshSource& m = s.mesh();
      const std::string f = field + ".mesh";
      out.kind = SetSourcePlan::Kind::kMesh;
      if (!m.has_asset()) return Invalid(f + ".asset", "required");
      if (auto st = ResolveAsset(m.asset(), f + ".asset", limits, out); !st.ok()) return st;
      // The file label names the file the way the spec did, so errors read
      // "set_ifs.maps[0].condensation.mesh: cow.obj: ...".
      auto mesh = LoadMesh(out.file, {MeshFileTypeFromName(out.file_format), out.file_label});
      if (!mesh.ok()) return Invalid(f, std::string(mesh.status().message()));
      const MeshTopology topo = AnalyzeTopology(*mesh);
      if (!topo.watertight())
        job.warnings.push_back(
            StrCat(f, ": mesh ", out.file_label, " is not watertight (", topo.boundary_edges,
                   " boundary and ", topo.nonmanifold_edges,
                   " non-manifold edges); its interior is estimated by a ray vote"));
      out.mesh = std::make_shared<const TriangleMesh>(std::move(*mesh));
      out.fit = !m.keep_coordinates();
      if (!(m.fit_margin_voxels() >= 0) || !std::isfinite(m.fit_margin_voxels()))
        return Invalid(f + ".fit_margin_voxels", "must be finite and >= 0");
      out.fit_margin_voxels = m.fit_margin_voxels() == 0 ? 2.0 : m.fit_margin_voxels();
      auto t = ComposeSteps(m.transform(), f + ".transform");
      if (!t.ok()) return t.status();
      out.transform = *t;
      if (!(m.shell_voxels() >= 0) || !std::isfinite(m.shell_voxels()))
        return Invalid(f + ".shell_voxels", "must be finite and >= 0");
      out.shell_voxels = m.shell_voxels();
      return absl::OkStatus();
    }
    case v1::SetSource::kGrid: {
      const v1::GridSource& g = s.grid();
      const std::string f = field + ".grid";
      out.kind = SetSourcePlan::Kind::kGrid;
      if (!g.has_asset()) return Invalid(f + ".asset", "required");
      if (auto st = ResolveAsset(g.asset(), f + ".asset", limits, out); !st.ok()) return st;
      // The server checked the upload in a sandbox and kept the grids it
      // read, re-written by Nimbus: read those, never the uploaded bytes.
      if (std::error_code ec; g.asset().source_case() == v1::Asset::kSha256 &&
                              std::filesystem::exists(LaunderedPath(out.file), ec))
        out.file = LaunderedPath(out.file);
      if (auto st = CheckLength(g.grid_name(), kMaxGridNameBytes, f + ".grid_name"); !st.ok())
        return st;
      out.grid_name = g.grid_name();
      if (!std::isfinite(g.threshold())) return Invalid(f + ".threshold", "must be finite");
      out.threshold = g.threshold() == 0 ? 0.5 : g.threshold();
      return absl::OkStatus();
    }
    case v1::SetSource::kSphere: {
      out.kind = SetSourcePlan::Kind::kSphere;
      if (!Finite(s.sphere().center())) return Invalid(field + ".sphere.center", "must be finite");
      out.center = ToVec3(s.sphere().center());
      out.radius = s.sphere().radius();
      return CheckPositive(out.radius, field + ".sphere.radius");
    }
    case v1::SetSource::kBox: {
      out.kind = SetSourcePlan::Kind::kBox;
      const v1::BoxSource& b = s.box();
      if (!Finite(b.min()) || !Finite(b.max())) return Invalid(field + ".box", "must be finite");
      out.box = {ToVec3(b.min()), ToVec3(b.max())};
      for (int a = 0; a < 3; ++a)
        if (!(out.box.max[a] > out.box.min[a]))
          return Invalid(field + ".box.max", "must exceed box.min on every axis");
      return absl::OkStatus();
    }
    case v1::SetSource::kTorus: {
      out.kind = SetSourcePlan::Kind::kTorus;
      const v1::TorusSource& t = s.torus();
      if (!Finite(t.center()) || !Finite(t.axis()))
        return Invalid(field + ".torus", "must be finite");
      out.center = ToVec3(t.center());
      out.axis = t.has_axis() ? ToVec3(t.axis()) : Vec3{0, 0, 1};
      if (Length(out.axis) == 0) return Invalid(field + ".torus.axis", "must not be zero");
      out.major_radius = t.major_radius();
      out.minor_radius = t.minor_radius();
      if (auto st = CheckPositive(out.major_radius, field + ".torus.major_radius"); !st.ok())
        return st;
      return CheckPositive(out.minor_radius, field + ".torus.minor_radius");
    }
    case v1::SetSource::kRandomBalls: {
      out.kind = SetSourcePlan::Kind::kRandomBalls;
      const v1::RandomBallsSource& r = s.random_balls();
      const std::string f = field + ".random_balls";
      if (!r.has_inside()) return Invalid(f + ".inside", "required");
      out.parts.emplace_back();
      if (auto st = ConvertSource(r.inside(), f + ".inside", limits, depth + 1, job, out.parts[0]);
          !st.ok())
        return st;
      if (r.count() < 0 || r.count() > 100000) return Invalid(f + ".count", "must be in 0..100000");
      out.balls.count = r.count() == 0 ? 24 : r.count();
      out.balls.min_radius = r.min_radius() == 0 ? 0.05 : r.min_radius();
      out.balls.max_radius = r.max_radius() == 0 ? 0.15 : r.max_radius();
      if (auto st = CheckPositive(out.balls.min_radius, f + ".min_radius"); !st.ok()) return st;
      if (auto st = CheckPositive(out.balls.max_radius, f + ".max_radius"); !st.ok()) return st;
      if (out.balls.max_radius < out.balls.min_radius)
        return Invalid(f + ".max_radius", "must be >= min_radius");
      out.balls.seed = r.seed();
      out.balls.clip_to_region = r.clip_to_region();
      return absl::OkStatus();
    }
    case v1::SetSource::kUnion: {
      out.kind = SetSourcePlan::Kind::kUnion;
      const std::string f = field + ".union.parts";
      if (s.union_().parts_size() == 0) return Invalid(f, "needs at least one part");
      out.parts.resize(size_t(s.union_().parts_size()));
      for (int i = 0; i < s.union_().parts_size(); ++i)
        if (auto st = ConvertSource(s.union_().parts(i), StrCat(f, "[", i, "]"), limits, depth + 1,
                                    job, out.parts[size_t(i)]);
            !st.ok())
          return st;
      return absl::OkStatus();
    }
    case v1::SetSource::KIND_NOT_SET:
      break;
  }
  return Invalid(field, "set one of: mesh, grid, sphere, box, torus, random_balls, union");
}

absl::Status ConvertSetMap(const v1::SetMap& m, const std::string& field, const Limits& limits,
                           JobPlan& job, SetMapPlan& out) {
  out.field = field;
  switch (m.kind()) {
    case v1::SET_MAP_KIND_UNSPECIFIED:
      out.kind = m.has_point() ? SetMapKind::kPoint : SetMapKind::kMedian;
      break;
    case v1::SET_MAP_KIND_MEDIAN:
      out.kind = SetMapKind::kMedian;
      break;
    case v1::SET_MAP_KIND_ROTATED_MEDIAN:
      out.kind = SetMapKind::kRotatedMedian;
      break;
    case v1::SET_MAP_KIND_CONSTANT:
      out.kind = SetMapKind::kConstant;
      break;
    case v1::SET_MAP_KIND_POINT:
      out.kind = SetMapKind::kPoint;
      break;
    default:
      return Invalid(field + ".kind", "unknown value");
  }
  if (out.kind == SetMapKind::kPoint) {
    if (!m.has_point()) return Invalid(field + ".point", "required for a point map");
    if (m.has_condensation())
      return Invalid(field + ".condensation", "a point map has no condensation set");
    auto p = ConvertMap(m.point(), field + ".point");
    if (!p.ok()) return p.status();
    out.point = std::move(*p);
    return absl::OkStatus();
  }
  if (m.has_point()) return Invalid(field + ".point", "only for point maps");
  if (!m.has_condensation()) return Invalid(field + ".condensation", "required");
  out.condensation.emplace();
  if (auto st = ConvertSource(m.condensation(), field + ".condensation", limits, 0, job,
                              *out.condensation);
      !st.ok())
    return st;
  out.median.bridge_max_jump = m.bridge_max_jump() == 0 ? 4 : std::max(0, int(m.bridge_max_jump()));
  if (m.bridge_max_jump() > 64) return Invalid(field + ".bridge_max_jump", "at most 64");
  if (m.has_rotation() && out.kind != SetMapKind::kRotatedMedian)
    return Invalid(field + ".rotation", "only for SET_MAP_KIND_ROTATED_MEDIAN");
  if (out.kind == SetMapKind::kRotatedMedian) {
    const v1::Rotation& r = m.rotation();
    out.rotated.median = out.median;
    if (!std::isfinite(r.degrees_per_unit()))
      return Invalid(field + ".rotation.degrees_per_unit", "must be finite");
    out.rotated.degrees_per_unit = r.degrees_per_unit() == 0 ? 90.0 : r.degrees_per_unit();
    if (!Finite(r.axis())) return Invalid(field + ".rotation.axis", "must be finite");
    out.rotated.axis = r.has_axis() ? ToVec3(r.axis()) : Vec3{0, 0, 1};
    if (Length(out.rotated.axis) == 0) return Invalid(field + ".rotation.axis", "must not be zero");
    out.rotated.superpose = !r.no_superpose();
  }
  return absl::OkStatus();
}

}  // namespace

namespace internal {

absl::Status ConvertSetSource(const v1::SetSource& s, const std::string& field,
                              const Limits& limits, JobPlan& job, SetSourcePlan& out) {
  return ConvertSource(s, field, limits, 0, job, out);
}

absl::Status ConvertSetIfs(const v1::SetIfs& s, const Limits& limits, JobPlan& job) {
  auto plan = std::make_shared<SetIfsPlan>();
  const Int3 r = job.frame.resolution;
  for (int a = 0; a < 3; ++a)
    if (r[a] > VoxelSet::kMaxResolution)
      return absl::ResourceExhaustedError(StrCat("grid.resolution[", a,
                                                 "]: set IFS jobs allow at most ",
                                                 VoxelSet::kMaxResolution, " voxels per axis"));
  if (s.maps_size() == 0) return Invalid("set_ifs.maps", "needs at least one map");
  if (s.maps_size() > std::min(limits.max_maps, 64))
    return absl::ResourceExhaustedError(StrCat("set_ifs.maps: ", s.maps_size(),
                                               " maps exceed the limit of ",
                                               std::min(limits.max_maps, 64)));
  double total = 0;
  for (int i = 0; i < s.maps_size(); ++i) {
    const std::string field = StrCat("set_ifs.maps[", i, "]");
    SetMapPlan m;
    if (auto st = ConvertSetMap(s.maps(i), field, limits, job, m); !st.ok()) return st;
    const double p = s.maps(i).probability();
    if (!(p >= 0) || !std::isfinite(p))
      return Invalid(field + ".probability", "must be finite and >= 0");
    total += p;
    std::string label = s.maps(i).name();
    if (label.empty()) label = i < 26 ? std::string(1, char('A' + i)) : StrCat("M", i);
    for (const std::string& other : plan->labels)
      if (other == label) return Invalid(field + ".name", StrCat("'", label, "' is used twice"));
    plan->labels.push_back(label);
    plan->maps.push_back(std::move(m));
  }
  for (int i = 0; i < s.maps_size(); ++i)
    plan->probabilities.push_back(total > 0 ? s.maps(i).probability() / total
                                            : 1.0 / s.maps_size());
  if (s.has_start()) {
    plan->start.emplace();
    if (auto st = ConvertSource(s.start(), "set_ifs.start", limits, 0, job, *plan->start); !st.ok())
      return st;
  }
  switch (s.algorithm_case()) {
    case v1::SetIfs::kRandom:
    case v1::SetIfs::ALGORITHM_NOT_SET: {
      if (!s.has_random()) return Invalid("set_ifs.random", "required (or give book)");
      const v1::SetRandomIteration& ri = s.random();
      if (ri.iterations() == 0) return Invalid("set_ifs.random.iterations", "must be > 0");
      // Warm-up set iterations cost what counted ones cost: both count
      // toward the limit.
      const uint64_t limit = std::min<uint64_t>(limits.max_iterations, uint64_t{1} << 24);
      if (ri.iterations() > limit)
        return absl::ResourceExhaustedError(StrCat("set_ifs.random.iterations: ", ri.iterations(),
                                                   " exceeds the limit of ", limit));
      if (uint64_t(ri.warmup()) > limit - ri.iterations())
        return absl::ResourceExhaustedError(
            StrCat("set_ifs.random.warmup: ", ri.warmup(), " warm-up plus ", ri.iterations(),
                   " iterations exceed the limit of ", limit, " set iterations"));
      plan->iterations = ri.iterations();
      plan->warmup = ri.warmup() == 0 ? 16 : ri.warmup();
      plan->seed = ri.seed();
      // Warm-up iterations are preparation: progress counts the counted ones.
      job.work = {plan->iterations, "set iterations"};
      break;
    }
    case v1::SetIfs::kBook: {
      const v1::SetBook& b = s.book();
      if (b.depth() < 1) return Invalid("set_ifs.book.depth", "must be >= 1");
      auto pages = BookPageCount(size_t(s.maps_size()), b.depth());
      if (!pages.ok() || *pages > kMaxBookPages)
        return Invalid("set_ifs.book.depth", StrCat(s.maps_size(), " maps to depth ", b.depth(),
                                                    " make more than ", kMaxBookPages, " pages"));
      plan->book = true;
      plan->depth = b.depth();
      plan->pages = *pages;
      plan->seed = b.seed();
      job.work = {*pages, "pages"};
      break;
    }
  }
  job.kind = std::move(*plan);
  return absl::OkStatus();
}

}  // namespace internal

}  // namespace nimbus::spec
