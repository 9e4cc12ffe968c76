// @brief The physics of an elastic IFS: one body per map, springs, gravity,
// gusty wind, a ground plane and sphere collisions, integrated with a fixed
// step by symplectic (default) or explicit Euler. A step is a pure function
// of the state, so a run gives the same bits on every machine and thread
// count.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "core/jelly/jelly_plan.h"

namespace nimbus {

/// @brief One body's dynamic coordinates. Rotation is a rotation vector
/// (radians) applied after the rest rotation; scale is an offset added to
/// the rest scale.
struct JellyBodyState {
  Vec3 position, velocity;
  Vec3 rotation, angular_velocity;
  Vec3 scale_offset, scale_velocity;
};

/// @brief The largest stable step and what sets it.
struct JellyStepLimit {
  /// Seconds; +inf when nothing oscillates.
  double max_dt = 0;
  /// Human-readable: "body 2 (mass 1, springs k = 400, damping 0)".
  std::string cause;
};

/// The step limit of `sim`: for every coordinate, with ω² and c bounded by
/// Gershgorin's theorem on the mass-scaled stiffness and damping, the
/// symplectic Euler condition ω²·dt² + 2·c·dt < 4 (for one undamped spring
/// on a mass, dt < 2·sqrt(m/k)).
JellyStepLimit StableStepLimit(const JellySim& sim);

class JellyWorld {
 public:
  /// INVALID_ARGUMENT when sim.dt is not below StableStepLimit or a body
  /// or spring is malformed (the converter names fields first).
  static absl::StatusOr<JellyWorld> Create(JellySim sim);

  /// Advances one fixed step.
  void Step();
  /// Adds impulse / mass to a body's velocity.
  void ApplyImpulse(int body, Vec3 impulse);
  /// Pulls a body towards `target` for `steps` steps with a critically
  /// damped spring (stiffness clamped to a quarter of the stable maximum).
  void AddDrag(int body, Vec3 target, double stiffness, uint64_t steps);

  /// Each body's map, M = M_T·M_RC⁻¹·M_R·M_RC·M_S, in body order.
  std::vector<Affine3> Maps() const;
  /// Kinetic plus spring (and rotation/scale spring) plus gravity energy.
  double Energy() const;

  const std::vector<JellyBodyState>& state() const { return state_; }
  const JellySim& sim() const { return sim_; }
  double time() const { return double(steps_) * sim_.dt; }
  uint64_t steps() const { return steps_; }

 private:
  struct Drag {
    int body;
    Vec3 target;
    double stiffness, damping;
    uint64_t steps_left;
  };
  // Accelerations of the three coordinate groups of every body.
  struct Accel {
    std::vector<Vec3> linear, angular, scale;
  };
  explicit JellyWorld(JellySim sim);
  Vec3 ExternalForce(int i) const;
  void AddSpringForces(std::vector<Vec3>& force) const;
  Accel Accelerations() const;
  void Ground();
  void Collide();

  JellySim sim_;
  std::vector<Affine3> rest_rotation_;
  std::vector<JellyBodyState> state_;
  std::vector<Drag> drags_;
  uint64_t steps_ = 0;
};

}  // namespace nimbus
