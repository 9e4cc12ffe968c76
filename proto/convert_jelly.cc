// jelly: bodies, springs, forces, integrator, frames and rendering
// (docs/jelly.md). Every error names its field; a time step beyond the
// springs' stability limit is refused with the substeps that would do.
#include <cmath>

#include "core/jelly/jelly_render.h"
#include "core/jelly/jelly_world.h"
#include "proto/convert_internal.h"

namespace nimbus::spec::internal {

namespace {

constexpr int kMaxBodies = 256;
constexpr uint32_t kMaxFrames = 10000;
constexpr uint32_t kMaxSubsteps = 100000;
constexpr double kMaxFps = 1000;
// Leaves (VRR) or points (chaos game) per frame: three leaf buffers of this
// many points stay near 1 GiB.
constexpr uint64_t kMaxLeaves = uint64_t{1} << 24;

absl::Status NonNegative(double x, const std::string& path) {
  NIMBUS_RETURN_IF_ERROR(CheckNumber(x, path));
  if (x < 0) return Invalid(path, StrCat("must be >= 0, got ", x));
  return absl::OkStatus();
}

absl::Status CheckVec(const v1::Vec3& v, const std::string& path) {
  if (!Finite(v)) return Invalid(path, "must be finite and within ±1e12");
  return absl::OkStatus();
}

absl::StatusOr<double> Positive(const std::optional<double>& x, double fallback,
                                const std::string& path) {
  if (!x) return fallback;
  NIMBUS_RETURN_IF_ERROR(CheckNumber(*x, path));
  if (!(*x > 0)) return Invalid(path, StrCat("must be > 0, got ", *x));
  return *x;
}

absl::Status ConvertScale(const v1::Scale& sc, Vec3& out, const std::string& path) {
  if (sc.has_xyz() && sc.uniform() != 0) return Invalid(path, "set only one of uniform or xyz");
  if (sc.has_xyz()) {
    NIMBUS_RETURN_IF_ERROR(CheckVec(sc.xyz(), path + ".xyz"));
    out = ToVec3(sc.xyz());
  } else if (sc.uniform() != 0) {
    NIMBUS_RETURN_IF_ERROR(CheckNumber(sc.uniform(), path + ".uniform"));
    out = {sc.uniform(), sc.uniform(), sc.uniform()};
  }
  return absl::OkStatus();
}

absl::StatusOr<JellyBody> ConvertBody(const v1::JellyBody& b, const std::string& path) {
  JellyBody o;
  NIMBUS_ASSIGN_OR_RETURN(
      o.mass, Positive(b.has_mass() ? std::optional(b.mass()) : std::nullopt, 1, path + ".mass"));
  NIMBUS_ASSIGN_OR_RETURN(o.inertia, Positive(b.has_inertia() ? std::optional(b.inertia())
                                                              : std::nullopt,
                                              1, path + ".inertia"));
  NIMBUS_RETURN_IF_ERROR(NonNegative(b.radius(), path + ".radius"));
  o.radius = b.radius();
  if (b.has_scale()) NIMBUS_RETURN_IF_ERROR(ConvertScale(b.scale(), o.scale, path + ".scale"));
  if (b.has_rotation()) {
    NIMBUS_RETURN_IF_ERROR(CheckVec(b.rotation().axis(), path + ".rotation.axis"));
    NIMBUS_RETURN_IF_ERROR(CheckNumber(b.rotation().degrees(), path + ".rotation.degrees"));
    if (Length(ToVec3(b.rotation().axis())) == 0)
      return Invalid(path + ".rotation.axis", "must not be zero");
    o.rotation_axis = ToVec3(b.rotation().axis());
    o.rotation_degrees = b.rotation().degrees();
  }
  NIMBUS_RETURN_IF_ERROR(CheckVec(b.rotation_center(), path + ".rotation_center"));
  NIMBUS_RETURN_IF_ERROR(CheckVec(b.position(), path + ".position"));
  NIMBUS_RETURN_IF_ERROR(CheckVec(b.velocity(), path + ".velocity"));
  NIMBUS_RETURN_IF_ERROR(CheckVec(b.lever(), path + ".lever"));
  o.rotation_center = ToVec3(b.rotation_center());
  o.position = ToVec3(b.position());
  o.velocity = ToVec3(b.velocity());
  o.lever = ToVec3(b.lever());
  o.dynamic_rotation = b.dynamic_rotation();
  o.dynamic_scale = b.dynamic_scale();
  NIMBUS_RETURN_IF_ERROR(NonNegative(b.rotation_stiffness(), path + ".rotation_stiffness"));
  NIMBUS_RETURN_IF_ERROR(NonNegative(b.rotation_damping(), path + ".rotation_damping"));
  NIMBUS_RETURN_IF_ERROR(NonNegative(b.scale_stiffness(), path + ".scale_stiffness"));
  NIMBUS_RETURN_IF_ERROR(NonNegative(b.scale_damping(), path + ".scale_damping"));
  o.rotation_stiffness = b.rotation_stiffness();
  o.rotation_damping = b.rotation_damping();
  o.scale_stiffness = b.scale_stiffness();
  o.scale_damping = b.scale_damping();
  return o;
}

absl::Status CheckBodyIndex(int32_t i, int n, const std::string& path) {
  if (i < 0 || i >= n)
    return Invalid(path, StrCat("no body ", i, " (bodies has ", n, " entries, 0..", n - 1, ")"));
  return absl::OkStatus();
}

absl::StatusOr<JellySpring> ConvertSpring(const v1::JellySpring& s,
                                          const std::vector<JellyBody>& bodies,
                                          const std::string& path) {
  const int n = int(bodies.size());
  JellySpring o;
  NIMBUS_RETURN_IF_ERROR(CheckBodyIndex(s.body_a(), n, path + ".body_a"));
  o.a = s.body_a();
  switch (s.other_case()) {
    case v1::JellySpring::kBodyB:
      NIMBUS_RETURN_IF_ERROR(CheckBodyIndex(s.body_b(), n, path + ".body_b"));
      if (s.body_b() == s.body_a()) return Invalid(path + ".body_b", "must differ from body_a");
      o.b = s.body_b();
      break;
    case v1::JellySpring::kAnchor:
      NIMBUS_RETURN_IF_ERROR(CheckVec(s.anchor(), path + ".anchor"));
      o.anchor = ToVec3(s.anchor());
      break;
    case v1::JellySpring::OTHER_NOT_SET:
      return Invalid(path, "set body_b or anchor");
  }
  NIMBUS_RETURN_IF_ERROR(NonNegative(s.stiffness(), path + ".stiffness"));
  NIMBUS_RETURN_IF_ERROR(NonNegative(s.damping(), path + ".damping"));
  o.stiffness = s.stiffness();
  o.damping = s.damping();
  const Vec3 other = o.b < 0 ? o.anchor : bodies[o.b].position;
  o.rest_length = Length(other - bodies[o.a].position);
  if (s.has_rest_length()) {
    NIMBUS_RETURN_IF_ERROR(NonNegative(s.rest_length(), path + ".rest_length"));
    o.rest_length = s.rest_length();
  }
  return o;
}

absl::Status ConvertForces(const v1::Jelly& j, JellySim& sim) {
  if (j.has_gravity()) {
    NIMBUS_RETURN_IF_ERROR(CheckVec(j.gravity(), "jelly.gravity"));
    sim.gravity = ToVec3(j.gravity());
  }
  const v1::JellyWind& w = j.wind();
  NIMBUS_RETURN_IF_ERROR(CheckVec(w.velocity(), "jelly.wind.velocity"));
  NIMBUS_RETURN_IF_ERROR(NonNegative(w.drag(), "jelly.wind.drag"));
  NIMBUS_RETURN_IF_ERROR(NonNegative(w.gust_strength(), "jelly.wind.gust_strength"));
  NIMBUS_RETURN_IF_ERROR(NonNegative(w.gust_scale(), "jelly.wind.gust_scale"));
  NIMBUS_RETURN_IF_ERROR(NonNegative(w.gust_frequency(), "jelly.wind.gust_frequency"));
  sim.wind = {ToVec3(w.velocity()), w.drag(), w.gust_strength(),
              w.gust_scale() == 0 ? 1 : w.gust_scale(),
              w.gust_frequency() == 0 ? 1 : w.gust_frequency(), w.seed()};
  if (j.has_ground()) {
    const v1::JellyGround& g = j.ground();
    sim.ground.enabled = true;
    NIMBUS_RETURN_IF_ERROR(CheckNumber(g.height(), "jelly.ground.height"));
    sim.ground.height = g.height();
    if (g.has_restitution()) sim.ground.restitution = g.restitution();
    if (g.has_friction()) sim.ground.friction = g.friction();
    if (!(sim.ground.restitution >= 0 && sim.ground.restitution <= 1))
      return Invalid("jelly.ground.restitution", StrCat("must be in [0, 1], got ", g.restitution()));
    NIMBUS_RETURN_IF_ERROR(NonNegative(sim.ground.friction, "jelly.ground.friction"));
  }
  if (j.has_collisions()) {
    sim.collisions = true;
    if (j.collisions().has_restitution()) sim.collision_restitution = j.collisions().restitution();
    if (!(sim.collision_restitution >= 0 && sim.collision_restitution <= 1))
      return Invalid("jelly.collisions.restitution",
                     StrCat("must be in [0, 1], got ", sim.collision_restitution));
  }
  switch (j.integrator()) {
    case v1::JELLY_INTEGRATOR_UNSPECIFIED:
    case v1::JELLY_INTEGRATOR_SYMPLECTIC_EULER:
      sim.integrator = JellyIntegrator::kSymplecticEuler;
      break;
    case v1::JELLY_INTEGRATOR_EXPLICIT_EULER:
      sim.integrator = JellyIntegrator::kExplicitEuler;
      break;
    default:
      return Invalid("jelly.integrator", StrCat("unknown value ", int(j.integrator())));
  }
  return absl::OkStatus();
}

absl::Status ConvertTiming(const v1::Jelly& j, JellyPlan& p) {
  if (j.frames() == 0 || j.frames() > kMaxFrames)
    return Invalid("jelly.frames", StrCat("must be in [1, ", kMaxFrames, "], got ", j.frames()));
  p.frames = j.frames();
  if (!(j.fps() >= 0 && j.fps() <= kMaxFps))
    return Invalid("jelly.fps", StrCat("must be in (0, ", kMaxFps, "], got ", j.fps()));
  p.fps = j.fps() == 0 ? 24 : j.fps();
  if (j.substeps() > kMaxSubsteps)
    return Invalid("jelly.substeps", StrCat("must be at most ", kMaxSubsteps, ", got ", j.substeps()));
  p.substeps = j.substeps() == 0 ? 10 : j.substeps();
  p.sim.dt = 1.0 / (p.fps * p.substeps);
  // The springs' stability rule: refuse, and say how many substeps would do.
  const JellyStepLimit limit = StableStepLimit(p.sim);
  if (!(p.sim.dt < limit.max_dt)) {
    const double need = std::floor(1.0 / (p.fps * limit.max_dt)) + 1;
    return Invalid("jelly.substeps",
                   StrCat("the physics step dt = 1/(fps·substeps) = ", p.sim.dt,
                          " s is beyond the stability limit ", limit.max_dt, " s (about 2·sqrt(m/k)) set by ",
                          limit.cause, "; use at least ", need, " substeps or softer springs"));
  }
  return absl::OkStatus();
}

absl::Status ConvertRender(const v1::Jelly& j, JellyPlan& p, uint64_t& leaves) {
  JellyRender& r = p.render;
  r.seed = j.seed();
  if (j.start_points_size() > 0) r.start_points.clear();
  for (int i = 0; i < j.start_points_size(); ++i) {
    NIMBUS_RETURN_IF_ERROR(CheckVec(j.start_points(i), StrCat("jelly.start_points[", i, "]")));
    r.start_points.push_back(ToVec3(j.start_points(i)));
  }
  switch (j.render()) {
    case v1::JELLY_RENDER_MODE_UNSPECIFIED:
    case v1::JELLY_RENDER_MODE_VRR:
      r.mode = JellyRenderMode::kVrr;
      r.depth = j.depth() == 0 ? 4 : j.depth();
      leaves = VrrLeafCount(p.sim.bodies.size(), r.depth, r.start_points.size());
      if (leaves > kMaxLeaves)
        return Invalid("jelly.depth", StrCat("gives ", p.sim.bodies.size(), "^", r.depth, " × ",
                                             r.start_points.size(), " leaves; at most ", kMaxLeaves,
                                             " per frame"));
      return absl::OkStatus();
    case v1::JELLY_RENDER_MODE_CHAOS_GAME:
      r.mode = JellyRenderMode::kChaosGame;
      if (j.points() == 0 || j.points() > kMaxLeaves)
        return Invalid("jelly.points", StrCat("must be in [1, ", kMaxLeaves, "], got ", j.points()));
      r.points = leaves = j.points();
      // By linear size, |det S|^(1/3): weights by volume would starve thin
      // maps (a trunk) of points.
      for (const JellyBody& b : p.sim.bodies)
        r.weights.push_back(std::max(1e-9, std::cbrt(std::abs(b.scale.x * b.scale.y * b.scale.z))));
      return absl::OkStatus();
    default:
      return Invalid("jelly.render", StrCat("unknown value ", int(j.render())));
  }
}

absl::StatusOr<JellyPoke> ConvertImpulse(const v1::JellyImpulse& m, const JellyPlan& p,
                                         const std::string& path) {
  if (m.frame() < 1 || m.frame() >= p.frames)
    return Invalid(path + ".frame", StrCat("must be in [1, ", p.frames, "), got ", m.frame()));
  NIMBUS_ASSIGN_OR_RETURN(JellyPoke o,
                          ConvertJellyPush(m.push(), int(p.sim.bodies.size()), path + ".push"));
  o.frame = m.frame();
  return o;
}

}  // namespace

absl::Status ConvertJelly(const v1::Jelly& j, const Limits& limits, JobPlan& plan) {
  JellyPlan p;
  const int n = j.bodies_size();
  if (n == 0) return Invalid("jelly.bodies", "required: one body per IFS map");
  if (n > kMaxBodies || n > limits.max_maps)
    return absl::ResourceExhaustedError(
        StrCat("jelly.bodies: ", n, " bodies exceed the limit of ", std::min(kMaxBodies, limits.max_maps)));
  for (int i = 0; i < n; ++i) {
    NIMBUS_ASSIGN_OR_RETURN(JellyBody b, ConvertBody(j.bodies(i), StrCat("jelly.bodies[", i, "]")));
    p.sim.bodies.push_back(b);
  }
  for (int i = 0; i < j.springs_size(); ++i) {
    NIMBUS_ASSIGN_OR_RETURN(JellySpring s, ConvertSpring(j.springs(i), p.sim.bodies,
                                                         StrCat("jelly.springs[", i, "]")));
    p.sim.springs.push_back(s);
  }
  NIMBUS_RETURN_IF_ERROR(ConvertForces(j, p.sim));
  NIMBUS_RETURN_IF_ERROR(ConvertTiming(j, p));
  uint64_t leaves = 0;
  NIMBUS_RETURN_IF_ERROR(ConvertRender(j, p, leaves));
  if (leaves * p.frames > limits.max_iterations)
    return absl::ResourceExhaustedError(StrCat("jelly.frames: ", p.frames, " frames of ", leaves,
                                               " leaves exceed the server limit of ",
                                               limits.max_iterations, " points"));
  for (int i = 0; i < j.impulses_size(); ++i) {
    NIMBUS_ASSIGN_OR_RETURN(JellyPoke poke,
                            ConvertImpulse(j.impulses(i), p, StrCat("jelly.impulses[", i, "]")));
    p.impulses.push_back(poke);
  }
  p.velocity_grid = !j.no_velocity_grid();
  if (p.sim.integrator == JellyIntegrator::kExplicitEuler && !p.sim.springs.empty())
    plan.warnings.push_back(
        "jelly.integrator: explicit Euler gains energy on undamped springs (a factor "
        "1 + (ω·dt)² per step); symplectic Euler does not");
  for (const JellyBody& b : p.sim.bodies)
    plan.contraction_factors.push_back(
        (Affine3::Rotate(b.rotation_axis, b.rotation_degrees) * Affine3::Scale(b.scale))
            .ContractionFactor());
  plan.work = {p.frames, "frames"};
  plan.kind = std::move(p);
  return absl::OkStatus();
}

}  // namespace nimbus::spec::internal

namespace nimbus::spec {

using namespace internal;  // NOLINT: converter helpers

absl::StatusOr<JellyPoke> ConvertJellyPush(const v1::JellyPush& m, int bodies,
                                           const std::string& path) {
  JellyPoke o;
  NIMBUS_RETURN_IF_ERROR(CheckBodyIndex(m.body(), bodies, path + ".body"));
  o.body = m.body();
  switch (m.action_case()) {
    case v1::JellyPush::kImpulse:
      NIMBUS_RETURN_IF_ERROR(CheckVec(m.impulse(), path + ".impulse"));
      o.vector = ToVec3(m.impulse());
      return o;
    case v1::JellyPush::kDragTarget:
      NIMBUS_RETURN_IF_ERROR(CheckVec(m.drag_target(), path + ".drag_target"));
      NIMBUS_RETURN_IF_ERROR(NonNegative(m.drag_stiffness(), path + ".drag_stiffness"));
      if (m.drag_frames() > kMaxFrames)
        return Invalid(path + ".drag_frames",
                       StrCat("must be at most ", kMaxFrames, ", got ", m.drag_frames()));
      o.kind = JellyPoke::Kind::kDrag;
      o.vector = ToVec3(m.drag_target());
      o.stiffness = m.drag_stiffness() == 0 ? 50 : m.drag_stiffness();
      o.frames = m.drag_frames() == 0 ? 1 : m.drag_frames();
      return o;
    case v1::JellyPush::ACTION_NOT_SET:
      break;
  }
  return Invalid(path, "set impulse or drag_target");
}

}  // namespace nimbus::spec
