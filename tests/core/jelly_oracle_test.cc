// The jelly physics against closed forms (docs/jelly.md): the spring force
// F = -k·(length - rest) along the spring, by the first step of stretched
// and compressed springs and by the period 2π·sqrt(m/k) of a body on an
// anchored spring; the ground by a dropped body that lands on the step
// the symplectic fall predicts, leaves with restitution times its impact
// speed, loses μ(1+e) times that speed to friction and then rests on it;
// wind drag by the discrete relaxation it implies, a head-on collision
// by momentum and restitution, and a dynamic scale by the balance of its
// spring against the force at the lever.
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>

#include "core/jelly/jelly_world.h"
#include "tests/support/jelly_oracles.h"

namespace nimbus {
namespace {

// Bodies of mass 1 and 2 at x = 0 and x = `b`, a spring of rest length 1
// and k = 100 between them, nothing else.
JellyWorld Pair(double b, double dt) {
  JellySim sim;
  sim.gravity = {0, 0, 0};
  sim.dt = dt;
  JellyBody first, second;
  second.mass = 2;
  second.position = {b, 0, 0};
  sim.bodies = {first, second};
  sim.springs.push_back({0, 1, {}, 1.0, 100, 0});
  auto world = JellyWorld::Create(sim);
  EXPECT_TRUE(world.ok()) << world.status();
  return *std::move(world);
}

// Stretched by 0.5: a force of 50 pulls the bodies together, so after one
// step of 1 ms the first moves at +50 mm/s and the second at -25 mm/s,
// each having moved v·dt (symplectic Euler moves with the new speed).
// Compressed by 0.4: 40 pushes them apart.
TEST(JellyOracle, SpringForceIsMinusKTimesTheStretchAlongTheSpring) {
  const double dt = 1e-3;
  JellyWorld stretched = Pair(1.5, dt);
  stretched.Step();
  EXPECT_NEAR(stretched.state()[0].velocity.x, 50 * dt, 1e-15);
  EXPECT_NEAR(stretched.state()[1].velocity.x, -25 * dt, 1e-15);
  EXPECT_NEAR(stretched.state()[0].position.x, 50 * dt * dt, 1e-15);
  EXPECT_NEAR(stretched.state()[1].position.x, 1.5 - 25 * dt * dt, 1e-15);
  EXPECT_EQ(stretched.state()[0].velocity.y, 0);
  JellyWorld compressed = Pair(0.6, dt);
  compressed.Step();
  EXPECT_NEAR(compressed.state()[0].velocity.x, -40 * dt, 1e-15);
  EXPECT_NEAR(compressed.state()[1].velocity.x, 20 * dt, 1e-15);
}

// m = 0.5 on an anchored spring of k = 50 and rest length 0: ω = 10 rad/s,
// x(t) = 0.2·cos(ωt). Symplectic Euler at ω·dt = 1e-3 keeps the amplitude
// within about ω·dt/2 of it and the phase within (ω·dt)²/24 per step.
TEST(JellyOracle, AnchoredSpringOscillatesWithPeriodTwoPiRootMOverK) {
  JellySim sim;
  sim.gravity = {0, 0, 0};
  sim.dt = 1e-4;
  JellyBody b;
  b.mass = 0.5;
  b.position = {0.2, 0, 0};
  sim.bodies = {b};
  sim.springs.push_back({0, -1, {0, 0, 0}, 0.0, 50, 0});
  auto world = JellyWorld::Create(sim);
  ASSERT_TRUE(world.ok()) << world.status();
  const double period = 2 * std::numbers::pi * std::sqrt(0.5 / 50);
  for (int step = 1; step <= 12000; ++step) {
    world->Step();
    if (step % 500) continue;
    const double t = world->time();
    ASSERT_NEAR(world->state()[0].position.x, 0.2 * std::cos(10 * t), 1e-3) << "t " << t;
  }
  EXPECT_GT(world->time(), 1.9 * period);
}

// Dropped from 1 m onto a ground at 0.2 with radius 0.1 (contact at 0.3),
// restitution 0.5, friction 0.05, sliding at 0.8 m/s.
TEST(JellyOracle, DroppedBodyLandsBouncesAndSlowsByTheGroundRule) {
  const double g = 9.81, dt = 1e-3, y0 = 1, contact = 0.3;
  JellySim sim;
  sim.gravity = {0, -g, 0};
  sim.dt = dt;
  sim.ground = {true, 0.2, 0.5, 0.05};
  JellyBody b;
  b.radius = 0.1;
  b.position = {0, y0, 0};
  b.velocity = {0.8, 0, 0};
  sim.bodies = {b};
  auto world = JellyWorld::Create(sim);
  ASSERT_TRUE(world.ok()) << world.status();
  const uint64_t land = testing::SymplecticLandingStep(y0, contact, g, dt);
  ASSERT_GT(land, 300u);  // about sqrt(2·0.7/g)/dt = 378
  for (uint64_t n = 1; n < land; ++n) {
    world->Step();
    ASSERT_NEAR(world->state()[0].position.y, testing::SymplecticFallHeight(y0, g, dt, n), 1e-12)
        << "step " << n;
  }
  world->Step();
  const JellyBodyState& s = world->state()[0];
  const double impact = g * double(land) * dt;  // speed just before the contact
  EXPECT_NEAR(s.position.y, contact, 1e-15) << "the body stops on the ground";
  EXPECT_NEAR(s.velocity.y, 0.5 * impact, 1e-12) << "restitution 0.5";
  // Coulomb: the tangential speed drops by μ times the normal impulse per
  // mass, (1 + e)·impact.
  EXPECT_NEAR(s.velocity.x, 0.8 - 0.05 * 1.5 * impact, 1e-12);
  EXPECT_GT(s.velocity.x, 0);
}

// With no bounce the body comes to rest exactly on the ground and stays.
TEST(JellyOracle, BodyWithoutBounceRestsOnTheGround) {
  JellySim sim;
  sim.dt = 1e-3;
  sim.ground = {true, -0.5, 0, 0.5};
  JellyBody b;
  b.radius = 0.25;
  b.position = {0, 0.5, 0};
  sim.bodies = {b};
  auto world = JellyWorld::Create(sim);
  ASSERT_TRUE(world.ok()) << world.status();
  const uint64_t land = testing::SymplecticLandingStep(0.5, -0.25, 9.81, 1e-3);
  for (uint64_t n = 0; n < land + 500; ++n) world->Step();
  EXPECT_EQ(world->state()[0].position.y, -0.25);
  EXPECT_EQ(world->state()[0].velocity.y, 0);
}

// Drag c·(w - v) on a mass m with no other force: each symplectic step
// multiplies w - v by (1 - c·dt/m), so v_n = w·(1 - (1 - c·dt/m)^n).
TEST(JellyOracle, WindDragRelaxesTheVelocityTowardsTheWind) {
  JellySim sim;
  sim.gravity = {0, 0, 0};
  sim.dt = 0.01;
  sim.wind.velocity = {1, 0, -2};
  sim.wind.drag = 0.5;
  JellyBody b;
  b.mass = 2;
  sim.bodies = {b};
  auto world = JellyWorld::Create(sim);
  ASSERT_TRUE(world.ok()) << world.status();
  for (int n = 1; n <= 400; ++n) {
    world->Step();
    const double left = std::pow(1 - 0.5 * 0.01 / 2, n);
    ASSERT_NEAR(world->state()[0].velocity.x, 1 - left, 1e-12) << n;
    ASSERT_NEAR(world->state()[0].velocity.z, -2 * (1 - left), 1e-12) << n;
  }
}

// Masses 1 and 3 at 2 and -1 m/s meet head on with restitution 0.5:
// momentum 2 - 3 = -1 is kept and the closing speed 3 becomes a parting
// speed 1.5, so they leave at -1.375 and +0.125 m/s.
TEST(JellyOracle, HeadOnCollisionKeepsMomentumAndScalesTheRelativeSpeed) {
  JellySim sim;
  sim.gravity = {0, 0, 0};
  sim.dt = 1e-3;
  sim.collisions = true;
  sim.collision_restitution = 0.5;
  JellyBody a, b;
  a.radius = b.radius = 0.1;
  a.position = {-0.5, 0, 0};
  a.velocity = {2, 0, 0};
  b.mass = 3;
  b.position = {0.5, 0, 0};
  b.velocity = {-1, 0, 0};
  sim.bodies = {a, b};
  auto world = JellyWorld::Create(sim);
  ASSERT_TRUE(world.ok()) << world.status();
  for (int n = 0; n < 600; ++n) world->Step();  // they meet at t ≈ 0.27 s
  EXPECT_NEAR(world->state()[0].velocity.x, -1.375, 1e-12);
  EXPECT_NEAR(world->state()[1].velocity.x, 0.125, 1e-12);
  EXPECT_GT(world->state()[1].position.x - world->state()[0].position.x, 0.2);
}

// Gravity m·g acting at the lever point (0, 0.5, 0) of a body with dynamic
// scale pulls its y scale until the scale spring balances it:
// k_s·Δs_y = lever_y·F_y, so Δs_y = -m·g·0.5 / k_s; x and z keep theirs.
TEST(JellyOracle, DynamicScaleSettlesWhereItsSpringBalancesTheLeverForce) {
  JellySim sim;
  sim.dt = 1e-3;
  JellyBody b;
  b.mass = 1.5;
  b.lever = {0, 0.5, 0};
  b.dynamic_scale = true;
  b.inertia = 0.1;
  b.scale_stiffness = 20;
  b.scale_damping = 2 * std::sqrt(20 * 0.1);  // critical
  sim.bodies = {b};
  auto world = JellyWorld::Create(sim);
  ASSERT_TRUE(world.ok()) << world.status();
  for (int n = 0; n < 5000; ++n) world->Step();
  const JellyBodyState& s = world->state()[0];
  EXPECT_NEAR(s.scale_offset.y, -1.5 * 9.81 * 0.5 / 20, 1e-6);
  EXPECT_EQ(s.scale_offset.x, 0);
  EXPECT_EQ(s.scale_offset.z, 0);
  // The map scales y by 1 + Δs_y about the body's position.
  const Affine3 m = world->Maps()[0];
  const Vec3 p = m.Apply({0, 1, 0}) - m.Apply({0, 0, 0});
  EXPECT_NEAR(p.y, 1 - 1.5 * 9.81 * 0.5 / 20, 1e-6);
}

}  // namespace
}  // namespace nimbus
