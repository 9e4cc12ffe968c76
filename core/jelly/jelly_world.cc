#include "core/jelly/jelly_world.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "absl/strings/str_cat.h"
#include "core/jelly/gust_noise.h"

namespace nimbus {

namespace {

constexpr double kRadToDeg = 180.0 / M_PI;

// Rotation by the rotation vector `phi` (radians).
Affine3 RotationOf(Vec3 phi) {
  const double angle = Length(phi);
  if (angle == 0) return Affine3::Identity();
  return Affine3::Rotate(phi, angle * kRadToDeg);
}

// The largest dt with w2·dt² + 2·c·dt < 4 (symplectic Euler on
// x'' + c·x' + w2·x = 0); +inf when nothing bounds it.
double MaxStep(double w2, double c) {
  if (w2 <= 0 && c <= 0) return std::numeric_limits<double>::infinity();
  if (w2 <= 0) return 2 / c;
  return (-c + std::sqrt(c * c + 4 * w2)) / w2;
}

// Gershgorin bounds of the mass-scaled stiffness and damping at body i.
struct Bound {
  double w2 = 0, c = 0, k = 0, b = 0;
};

std::vector<Bound> SpringBounds(const JellySim& sim) {
  std::vector<Bound> out(sim.bodies.size());
  for (const JellySpring& s : sim.springs) {
    const double ma = sim.bodies[s.a].mass;
    out[s.a].w2 += s.stiffness / ma;
    out[s.a].c += s.damping / ma;
    out[s.a].k += s.stiffness;
    out[s.a].b += s.damping;
    if (s.b < 0) continue;
    const double mb = sim.bodies[s.b].mass;
    const double root = std::sqrt(ma * mb);
    out[s.b].w2 += s.stiffness / mb;
    out[s.b].c += s.damping / mb;
    out[s.b].k += s.stiffness;
    out[s.b].b += s.damping;
    // Off-diagonal terms, once in each row.
    out[s.a].w2 += s.stiffness / root;
    out[s.b].w2 += s.stiffness / root;
    out[s.a].c += s.damping / root;
    out[s.b].c += s.damping / root;
  }
  for (size_t i = 0; i < out.size(); ++i) out[i].c += sim.wind.drag / sim.bodies[i].mass;
  return out;
}

}  // namespace

JellyStepLimit StableStepLimit(const JellySim& sim) {
  JellyStepLimit best{std::numeric_limits<double>::infinity(), "nothing oscillates"};
  auto consider = [&](double w2, double c, const std::string& cause) {
    const double dt = MaxStep(w2, c);
    if (dt < best.max_dt) best = {dt, cause};
  };
  const std::vector<Bound> bounds = SpringBounds(sim);
  for (size_t i = 0; i < sim.bodies.size(); ++i) {
    const JellyBody& b = sim.bodies[i];
    consider(bounds[i].w2, bounds[i].c,
             absl::StrCat("body ", i, " (mass ", b.mass, ", springs k = ", bounds[i].k,
                          ", damping ", bounds[i].b, ")"));
    if (b.dynamic_rotation)
      consider(b.rotation_stiffness / b.inertia, b.rotation_damping / b.inertia,
               absl::StrCat("body ", i, "'s rotation (inertia ", b.inertia, ", k = ",
                            b.rotation_stiffness, ")"));
    if (b.dynamic_scale)
      consider(b.scale_stiffness / b.inertia, b.scale_damping / b.inertia,
               absl::StrCat("body ", i, "'s scale (inertia ", b.inertia, ", k = ",
                            b.scale_stiffness, ")"));
  }
  return best;
}

JellyWorld::JellyWorld(JellySim sim) : sim_(std::move(sim)) {
  for (const JellyBody& b : sim_.bodies) {
    rest_rotation_.push_back(Affine3::Rotate(b.rotation_axis, b.rotation_degrees));
    JellyBodyState s;
    s.position = b.position;
    s.velocity = b.velocity;
    state_.push_back(s);
  }
}

absl::StatusOr<JellyWorld> JellyWorld::Create(JellySim sim) {
  const int n = int(sim.bodies.size());
  if (n == 0) return absl::InvalidArgumentError("a jelly needs at least one body");
  for (int i = 0; i < n; ++i)
    if (!(sim.bodies[i].mass > 0) || !(sim.bodies[i].inertia > 0))
      return absl::InvalidArgumentError(absl::StrCat("body ", i, ": mass and inertia must be > 0"));
  for (const JellySpring& s : sim.springs)
    if (s.a < 0 || s.a >= n || s.b >= n || s.a == s.b)
      return absl::InvalidArgumentError("a spring joins a missing body or a body to itself");
  if (!(sim.dt > 0)) return absl::InvalidArgumentError("dt must be > 0");
  const JellyStepLimit limit = StableStepLimit(sim);
  if (!(sim.dt < limit.max_dt))
    return absl::InvalidArgumentError(absl::StrCat("dt ", sim.dt, " s is beyond the stability limit ",
                                                   limit.max_dt, " s set by ", limit.cause));
  return JellyWorld(std::move(sim));
}

void JellyWorld::ApplyImpulse(int body, Vec3 impulse) {
  if (body < 0 || body >= int(state_.size())) return;
  state_[body].velocity = state_[body].velocity + (1.0 / sim_.bodies[body].mass) * impulse;
}

void JellyWorld::AddDrag(int body, Vec3 target, double stiffness, uint64_t steps) {
  if (body < 0 || body >= int(state_.size()) || steps == 0 || !(stiffness > 0)) return;
  const double m = sim_.bodies[body].mass;
  // A quarter of the largest stable stiffness for this body alone (ω·dt
  // <= 1), critically damped but with c·dt <= 1.
  const double k = std::min(stiffness, m / (sim_.dt * sim_.dt));
  const double b = std::min(2 * std::sqrt(k * m), m / sim_.dt);
  drags_.push_back({body, target, k, b, steps});
}

Vec3 JellyWorld::ExternalForce(int i) const {
  const JellyBody& b = sim_.bodies[i];
  const JellyBodyState& s = state_[i];
  Vec3 f = b.mass * sim_.gravity;
  const JellyWind& w = sim_.wind;
  if (w.drag > 0) {
    Vec3 wind = w.velocity;
    if (w.gust_strength > 0)
      wind = wind + w.gust_strength *
                        GustNoise(w.seed, w.gust_scale * s.position, w.gust_frequency * time());
    f = f + w.drag * (wind - s.velocity);
  }
  for (const Drag& d : drags_)
    if (d.body == i) f = f + d.stiffness * (d.target - s.position) - d.damping * s.velocity;
  return f;
}

void JellyWorld::AddSpringForces(std::vector<Vec3>& force) const {
  for (const JellySpring& sp : sim_.springs) {
    const JellyBodyState& a = state_[sp.a];
    const Vec3 pb = sp.b < 0 ? sp.anchor : state_[sp.b].position;
    const Vec3 vb = sp.b < 0 ? Vec3{} : state_[sp.b].velocity;
    const Vec3 d = pb - a.position;
    const double len = Length(d);
    if (len == 0) continue;  // no direction: the force's line is undefined
    const Vec3 u = (1.0 / len) * d;
    // Pulls a towards b when stretched; damping on the relative speed
    // along the spring.
    const double mag = sp.stiffness * (len - sp.rest_length) + sp.damping * Dot(vb - a.velocity, u);
    force[sp.a] = force[sp.a] + mag * u;
    if (sp.b >= 0) force[sp.b] = force[sp.b] - mag * u;
  }
}

JellyWorld::Accel JellyWorld::Accelerations() const {
  const size_t n = state_.size();
  std::vector<Vec3> force(n);
  AddSpringForces(force);
  Accel acc{std::vector<Vec3>(n), std::vector<Vec3>(n), std::vector<Vec3>(n)};
  for (size_t i = 0; i < n; ++i) {
    const JellyBody& b = sim_.bodies[i];
    const JellyBodyState& s = state_[i];
    const Vec3 ext = ExternalForce(int(i));
    acc.linear[i] = (1.0 / b.mass) * (force[i] + ext);
    if (!b.dynamic_rotation && !b.dynamic_scale) continue;
    // External forces act at the lever point; their generalised forces on
    // rotation and scale follow from how that point moves with each.
    const Affine3 rot = RotationOf(s.rotation) * rest_rotation_[i];
    const Vec3 sc = b.scale + s.scale_offset;
    const Vec3 local{sc.x * b.lever.x - b.rotation_center.x, sc.y * b.lever.y - b.rotation_center.y,
                     sc.z * b.lever.z - b.rotation_center.z};
    if (b.dynamic_rotation) {
      const Vec3 torque = Cross(rot.ApplyLinear(local), ext) - b.rotation_stiffness * s.rotation -
                          b.rotation_damping * s.angular_velocity;
      acc.angular[i] = (1.0 / b.inertia) * torque;
    }
    if (b.dynamic_scale) {
      const Vec3 fl{Dot({rot.m[0][0], rot.m[1][0], rot.m[2][0]}, ext),
                    Dot({rot.m[0][1], rot.m[1][1], rot.m[2][1]}, ext),
                    Dot({rot.m[0][2], rot.m[1][2], rot.m[2][2]}, ext)};
      const Vec3 gen{b.lever.x * fl.x, b.lever.y * fl.y, b.lever.z * fl.z};
      acc.scale[i] = (1.0 / b.inertia) * (gen - b.scale_stiffness * s.scale_offset -
                                           b.scale_damping * s.scale_velocity);
    }
  }
  return acc;
}

void JellyWorld::Step() {
  const Accel a = Accelerations();
  const double dt = sim_.dt;
  const bool symplectic = sim_.integrator == JellyIntegrator::kSymplecticEuler;
  // Symplectic Euler moves with the new velocity, explicit Euler with the old.
  auto advance = [&](Vec3& x, Vec3& v, Vec3 acc) {
    const Vec3 v_new = v + dt * acc;
    x = x + dt * (symplectic ? v_new : v);
    v = v_new;
  };
  for (size_t i = 0; i < state_.size(); ++i) {
    JellyBodyState& s = state_[i];
    advance(s.position, s.velocity, a.linear[i]);
    if (sim_.bodies[i].dynamic_rotation) advance(s.rotation, s.angular_velocity, a.angular[i]);
    if (sim_.bodies[i].dynamic_scale) advance(s.scale_offset, s.scale_velocity, a.scale[i]);
  }
  if (sim_.collisions) Collide();
  if (sim_.ground.enabled) Ground();
  for (Drag& d : drags_) --d.steps_left;
  std::erase_if(drags_, [](const Drag& d) { return d.steps_left == 0; });
  ++steps_;
}

void JellyWorld::Ground() {
  const JellyGround& g = sim_.ground;
  for (size_t i = 0; i < state_.size(); ++i) {
    JellyBodyState& s = state_[i];
    const double floor = g.height + sim_.bodies[i].radius;
    if (s.position.y >= floor) continue;
    s.position.y = floor;
    if (s.velocity.y >= 0) continue;
    // Bounce, and let Coulomb friction take at most mu times the normal
    // impulse off the sliding speed.
    const double vn = -s.velocity.y;
    s.velocity.y = g.restitution * vn;
    const Vec3 vt{s.velocity.x, 0, s.velocity.z};
    const double speed = Length(vt);
    if (speed == 0) continue;
    const double keep = std::max(0.0, 1 - g.friction * (1 + g.restitution) * vn / speed);
    s.velocity.x *= keep;
    s.velocity.z *= keep;
  }
}

void JellyWorld::Collide() {
  const size_t n = state_.size();
  for (size_t i = 0; i < n; ++i) {
    for (size_t j = i + 1; j < n; ++j) {
      const double reach = sim_.bodies[i].radius + sim_.bodies[j].radius;
      JellyBodyState& a = state_[i];
      JellyBodyState& b = state_[j];
      const Vec3 d = b.position - a.position;
      const double dist = Length(d);
      if (reach <= 0 || dist >= reach || dist == 0) continue;
      const Vec3 u = (1.0 / dist) * d;
      const double wa = 1 / sim_.bodies[i].mass, wb = 1 / sim_.bodies[j].mass;
      // Separate by inverse mass, then exchange a normal impulse.
      const double push = (reach - dist) / (wa + wb);
      a.position = a.position - (push * wa) * u;
      b.position = b.position + (push * wb) * u;
      const double vrel = Dot(b.velocity - a.velocity, u);
      if (vrel >= 0) continue;
      const double j_imp = -(1 + sim_.collision_restitution) * vrel / (wa + wb);
      a.velocity = a.velocity - (j_imp * wa) * u;
      b.velocity = b.velocity + (j_imp * wb) * u;
    }
  }
}

std::vector<Affine3> JellyWorld::Maps() const {
  std::vector<Affine3> maps;
  maps.reserve(state_.size());
  for (size_t i = 0; i < state_.size(); ++i) {
    const JellyBody& b = sim_.bodies[i];
    const JellyBodyState& s = state_[i];
    const Affine3 rc = Affine3::Translate(-1.0 * b.rotation_center);
    const Affine3 rc_inv = Affine3::Translate(b.rotation_center);
    const Affine3 r = RotationOf(s.rotation) * rest_rotation_[i];
    maps.push_back(Affine3::Translate(s.position) * rc_inv * r * rc *
                   Affine3::Scale(b.scale + s.scale_offset));
  }
  return maps;
}

double JellyWorld::Energy() const {
  double e = 0;
  for (size_t i = 0; i < state_.size(); ++i) {
    const JellyBody& b = sim_.bodies[i];
    const JellyBodyState& s = state_[i];
    e += 0.5 * b.mass * Dot(s.velocity, s.velocity) - b.mass * Dot(sim_.gravity, s.position);
    e += 0.5 * b.inertia * (Dot(s.angular_velocity, s.angular_velocity) +
                            Dot(s.scale_velocity, s.scale_velocity));
    e += 0.5 * b.rotation_stiffness * Dot(s.rotation, s.rotation);
    e += 0.5 * b.scale_stiffness * Dot(s.scale_offset, s.scale_offset);
  }
  for (const JellySpring& sp : sim_.springs) {
    const Vec3 pb = sp.b < 0 ? sp.anchor : state_[sp.b].position;
    const double stretch = Length(pb - state_[sp.a].position) - sp.rest_length;
    e += 0.5 * sp.stiffness * stretch * stretch;
  }
  return e;
}

}  // namespace nimbus
