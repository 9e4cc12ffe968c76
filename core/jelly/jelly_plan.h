// @brief The elastic IFS ("jelly") job kind's plan: bodies (one per IFS
// map), springs, forces, the integrator, the frames to render and how. Plain
// data, validated by proto/convert_jelly.cc; docs/jelly.md explains the model.
#pragma once

#include <cstdint>
#include <vector>

#include "core/base/geometry.h"

namespace nimbus {

/// @brief One IFS map as a body. Its map is M = M_T·M_RC⁻¹·M_R·M_RC·M_S:
/// scale, rotation about `rotation_center`, then the simulated translation
/// (the body's position). Translation is always dynamic; rotation and scale
/// may be, each pulled back to its rest value by its own spring.
struct JellyBody {
  double mass = 1;
  /// Collision sphere around the position, world units; 0: a point.
  double radius = 0;
  Vec3 scale{1, 1, 1};
  Vec3 rotation_axis{0, 0, 1};
  double rotation_degrees = 0;
  Vec3 rotation_center;
  /// Initial position (M_T's translation) and velocity.
  Vec3 position;
  Vec3 velocity;
  /// Where external forces act, in the map's own coordinates (before scale
  /// and rotation); it makes forces turn and stretch dynamic rotation and
  /// scale. Zero: external forces only move the body.
  Vec3 lever;
  bool dynamic_rotation = false;
  bool dynamic_scale = false;
  /// Inertia of the rotation and scale coordinates.
  double inertia = 1;
  double rotation_stiffness = 0, rotation_damping = 0;
  double scale_stiffness = 0, scale_damping = 0;
};

/// @brief A spring between two bodies' positions, or from a body to a
/// fixed anchor (`b` < 0). F = -k·(length - rest)·d̂ - b·(v_rel·d̂)·d̂.
struct JellySpring {
  int a = 0;
  int b = -1;
  Vec3 anchor;
  double rest_length = 0;
  double stiffness = 0;
  double damping = 0;
};

/// @brief Wind: a constant velocity plus gusts from a deterministic noise
/// field; bodies feel drag·(wind - velocity).
struct JellyWind {
  Vec3 velocity;
  double drag = 0;
  double gust_strength = 0;
  /// Gusts per world unit and per second (noise lattice frequencies).
  double gust_scale = 1;
  double gust_frequency = 1;
  uint64_t seed = 0;
};

/// @brief The ground plane y = height.
struct JellyGround {
  bool enabled = false;
  double height = 0;
  double restitution = 0.3;
  /// Coulomb friction coefficient against the normal impulse.
  double friction = 0.5;
};

enum class JellyIntegrator { kSymplecticEuler, kExplicitEuler };

/// @brief Everything the physics needs.
struct JellySim {
  std::vector<JellyBody> bodies;
  std::vector<JellySpring> springs;
  Vec3 gravity{0, -9.81, 0};
  JellyWind wind;
  JellyGround ground;
  bool collisions = false;
  double collision_restitution = 0.5;
  JellyIntegrator integrator = JellyIntegrator::kSymplecticEuler;
  /// Fixed time step, seconds.
  double dt = 1.0 / 240;
};

/// @brief A velocity change (impulse / mass) or a drag towards a point,
/// given to a body at a frame: by the spec, or by a poke on a running job.
struct JellyPoke {
  enum class Kind { kImpulse, kDrag };
  /// The first frame that shows it (>= 1): it acts just before the steps
  /// that lead to this frame.
  uint64_t frame = 1;
  int body = 0;
  Kind kind = Kind::kImpulse;
  /// Impulse (mass·velocity), or the drag's target point.
  Vec3 vector;
  /// Drag: spring stiffness (clamped to the stable range) and how many
  /// frames it pulls.
  double stiffness = 0;
  uint32_t frames = 1;
};

enum class JellyRenderMode { kVrr, kChaosGame };

/// @brief How a frame's maps become points.
struct JellyRender {
  JellyRenderMode mode = JellyRenderMode::kVrr;
  /// VRR: every composition of `depth` maps applied to each start point.
  uint32_t depth = 4;
  std::vector<Vec3> start_points{Vec3{}};
  /// Chaos game: points per frame, the same random addresses every frame
  /// so points correspond between frames.
  uint64_t points = 0;
  uint64_t seed = 0;
  /// Chaos game: map choice weights (|det S|^(1/3) of the rest scales);
  /// empty: uniform.
  std::vector<double> weights;
};

/// @brief A validated jelly job.
struct JellyPlan {
  JellySim sim;
  uint32_t frames = 1;
  double fps = 24;
  uint32_t substeps = 10;
  JellyRender render;
  std::vector<JellyPoke> impulses;
  /// Write the Vec3f grid "v" (world units per second).
  bool velocity_grid = true;
};

}  // namespace nimbus
