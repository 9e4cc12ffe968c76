// The jelly physics: energy kept by symplectic Euler, lost to damping,
// gained by explicit Euler; static sag m·g/k; the stability rule; the
// ground; the composed map M = M_T·M_RC⁻¹·M_R·M_RC·M_S.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>

#include "core/jelly/gust_noise.h"
#include "core/jelly/jelly_world.h"

namespace nimbus {
namespace {

// Two unit masses on a spring (k = 100, rest 1) stretched to 1.5, plus one
// anchored to the origin: three coupled oscillators, no gravity.
JellySim Oscillators(double damping, JellyIntegrator integrator, double dt) {
  JellySim sim;
  sim.gravity = {0, 0, 0};
  sim.integrator = integrator;
  sim.dt = dt;
  JellyBody a, b;
  a.position = {0, 0, 0};
  b.position = {1.5, 0.2, 0};
  sim.bodies = {a, b};
  sim.springs.push_back({0, 1, {}, 1.0, 100, damping});
  sim.springs.push_back({0, -1, {0, 0.3, 0}, 0.0, 50, damping});
  return sim;
}

TEST(JellyPhysics, SymplecticEulerKeepsEnergyWithinHalfAPercentOver1e4Steps) {
  // ω_max ≈ 16.6 rad/s, ω·dt ≈ 0.008: the modified energy symplectic
  // Euler keeps differs from the true one by O(ω·dt), with no drift.
  auto world = JellyWorld::Create(Oscillators(0, JellyIntegrator::kSymplecticEuler, 5e-4));
  ASSERT_TRUE(world.ok()) << world.status();
  const double e0 = world->Energy();
  ASSERT_GT(e0, 1);
  double worst = 0;
  for (int i = 0; i < 10000; ++i) {
    world->Step();
    worst = std::max(worst, std::abs(world->Energy() - e0) / e0);
  }
  EXPECT_LT(worst, 0.005);
}

TEST(JellyPhysics, ExplicitEulerGainsEnergyOnTheSameSystem) {
  auto world = JellyWorld::Create(Oscillators(0, JellyIntegrator::kExplicitEuler, 5e-4));
  ASSERT_TRUE(world.ok());
  const double e0 = world->Energy();
  for (int i = 0; i < 10000; ++i) world->Step();
  // Each step multiplies a mode's energy by about 1 + (ω·dt)².
  EXPECT_GT(world->Energy(), 1.2 * e0);
}

TEST(JellyPhysics, DampingMakesTheAmplitudeDecay) {
  JellySim sim;
  sim.gravity = {0, 0, 0};
  sim.dt = 1e-3;
  JellyBody b;
  b.position = {0.5, 0, 0};
  sim.bodies = {b};
  sim.springs.push_back({0, -1, {0, 0, 0}, 0.0, 100, 2.0});  // ζ = 0.1
  auto world = JellyWorld::Create(sim);
  ASSERT_TRUE(world.ok());
  // Peak |x| per period (T ≈ 0.628 s): strictly decreasing, by about
  // exp(-b/(2m)·T) = 0.53 each.
  std::vector<double> peaks;
  for (int period = 0; period < 8; ++period) {
    double peak = 0;
    for (int i = 0; i < 628; ++i) {
      world->Step();
      peak = std::max(peak, std::abs(world->state()[0].position.x));
    }
    peaks.push_back(peak);
  }
  for (size_t i = 1; i < peaks.size(); ++i) EXPECT_LT(peaks[i], 0.6 * peaks[i - 1]) << i;
  for (size_t i = 2; i < peaks.size(); ++i)
    EXPECT_NEAR(peaks[i] / peaks[i - 1], std::exp(-0.628), 0.05) << i;
  EXPECT_LT(peaks.back(), 0.02 * peaks.front());
}

TEST(JellyPhysics, StaticSagUnderGravityIsMgOverK) {
  for (double m : {0.5, 2.0}) {
    JellySim sim;
    sim.gravity = {0, -9.81, 0};
    sim.dt = 1e-3;
    JellyBody b;
    b.mass = m;
    b.position = {0, 1, 0};
    sim.bodies = {b};
    const double k = 200;
    sim.springs.push_back({0, -1, {0, 1, 0}, 0.0, k, 2 * std::sqrt(k * m)});  // critical
    auto world = JellyWorld::Create(sim);
    ASSERT_TRUE(world.ok());
    for (int i = 0; i < 20000; ++i) world->Step();
    EXPECT_NEAR(1 - world->state()[0].position.y, m * 9.81 / k, 1e-9) << m;
  }
}

TEST(JellyPhysics, StepLimitIsTwoRootMOverKForOneSpring) {
  JellySim sim;
  JellyBody b;
  b.mass = 4;
  sim.bodies = {b};
  sim.springs.push_back({0, -1, {0, 1, 0}, 1.0, 100, 0});
  EXPECT_NEAR(StableStepLimit(sim).max_dt, 2 * std::sqrt(4.0 / 100), 1e-12);
  sim.dt = 0.41;
  auto bad = JellyWorld::Create(sim);
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.status().message().find("stability limit"), std::string::npos);
  EXPECT_NE(bad.status().message().find("body 0"), std::string::npos);
  sim.dt = 0.39;
  EXPECT_TRUE(JellyWorld::Create(sim).ok());
  // Damping lowers it: ω²dt² + 2c·dt < 4.
  sim.springs[0].damping = 8;  // c = 2
  const double dt = StableStepLimit(sim).max_dt;
  EXPECT_NEAR(25 * dt * dt + 4 * dt, 4, 1e-9);
}

TEST(JellyPhysics, NoBodyEndsBelowTheGroundAndBouncesLoseEnergy) {
  JellySim sim;
  sim.dt = 1e-3;
  sim.ground = {true, 0.25, 0.5, 0.5};
  JellyBody b;
  b.radius = 0.1;
  b.position = {0, 2, 0};
  b.velocity = {1, 0, 0};
  sim.bodies = {b};
  auto world = JellyWorld::Create(sim);
  ASSERT_TRUE(world.ok());
  double top_after_bounce = 0;
  bool bounced = false;
  for (int i = 0; i < 3000; ++i) {
    world->Step();
    const JellyBodyState& s = world->state()[0];
    ASSERT_GE(s.position.y, 0.35) << i;
    if (s.velocity.y > 0) bounced = true;
    if (bounced) top_after_bounce = std::max(top_after_bounce, s.position.y);
  }
  EXPECT_TRUE(bounced);
  // Restitution 0.5 keeps a quarter of the fall height (1.65): about 0.41.
  EXPECT_NEAR(top_after_bounce - 0.35, 0.25 * 1.65, 0.02);
  // Friction took speed off the slide.
  EXPECT_LT(world->state()[0].velocity.x, 1.0);
}

TEST(JellyPhysics, SpheresDoNotInterpenetrate) {
  JellySim sim;
  sim.gravity = {0, 0, 0};
  sim.dt = 1e-3;
  sim.collisions = true;
  JellyBody a, b;
  a.radius = b.radius = 0.2;
  a.position = {-1, 0, 0};
  a.velocity = {2, 0, 0};
  b.position = {1, 0, 0};
  b.velocity = {-2, 0, 0};
  sim.bodies = {a, b};
  auto world = JellyWorld::Create(sim);
  ASSERT_TRUE(world.ok());
  for (int i = 0; i < 1000; ++i) {
    world->Step();
    const double gap = world->state()[1].position.x - world->state()[0].position.x;
    ASSERT_GE(gap, 0.4 - 1e-9) << i;
  }
  EXPECT_LT(world->state()[0].velocity.x, 0);  // bounced back
}

TEST(JellyPhysics, MapIsTranslationAfterRotationAboutCentreAfterScale) {
  JellySim sim;
  JellyBody b;
  b.scale = {0.5, 0.25, 2};
  b.rotation_axis = {0, 0, 1};
  b.rotation_degrees = 90;
  b.rotation_center = {1, 0, 0};
  b.position = {0, 0, 3};
  sim.bodies = {b};
  sim.gravity = {0, 0, 0};
  auto world = JellyWorld::Create(sim);
  ASSERT_TRUE(world.ok());
  const Affine3 m = world->Maps()[0];
  // p = (2, 4, 1): S -> (1, 1, 2); about (1,0,0) by 90° around z -> (0, 0, 2); + (0,0,3).
  const Vec3 q = m.Apply({2, 4, 1});
  EXPECT_NEAR(q.x, 0, 1e-12);
  EXPECT_NEAR(q.y, 0, 1e-12);
  EXPECT_NEAR(q.z, 5, 1e-12);
}

TEST(JellyPhysics, LeverTurnsADynamicRotationAgainstItsSpring) {
  // A constant sideways force F at lever height L turns the body until
  // k_rot·θ balances the torque L·F·cos θ (no other forces).
  JellySim sim;
  sim.gravity = {0, 0, 0};
  sim.dt = 1e-3;
  sim.wind = {{2, 0, 0}, 1.0, 0, 1, 1, 0};
  JellyBody b;
  b.lever = {0, 1, 0};
  b.dynamic_rotation = true;
  b.inertia = 0.1;
  b.rotation_stiffness = 4;
  b.rotation_damping = 1;
  sim.bodies = {b};
  // A stiff, heavily damped anchor holds the body (nearly) still.
  sim.springs.push_back({0, -1, {0, 0, 0}, 0.0, 1e4, 200});
  auto world = JellyWorld::Create(sim);
  ASSERT_TRUE(world.ok()) << world.status();
  for (int i = 0; i < 20000; ++i) world->Step();
  const JellyBodyState& s = world->state()[0];
  // At rest the drag is drag·(wind - 0) = 2 along x; the lever (0, 1, 0)
  // turned by θ about -z gives torque 2·cos θ.
  const double theta = -s.rotation.z;
  EXPECT_GT(theta, 0.3);
  EXPECT_NEAR(4 * theta, 2 * std::cos(theta), 1e-3);
}

TEST(GustNoise, DeterministicBoundedAndContinuous) {
  const Vec3 a = GustNoise(7, {0.3, 1.2, -0.7}, 2.5);
  const Vec3 b = GustNoise(7, {0.3, 1.2, -0.7}, 2.5);
  EXPECT_EQ(a, b);
  EXPECT_NE(a, GustNoise(8, {0.3, 1.2, -0.7}, 2.5));
  for (int i = 0; i < 1000; ++i) {
    const Vec3 p{0.013 * i, -0.007 * i, 0.021 * i};
    const Vec3 n = GustNoise(1, p, 0.01 * i);
    for (int c = 0; c < 3; ++c) ASSERT_LE(std::abs(n[c]), 1.0);
    const Vec3 m = GustNoise(1, p + Vec3{1e-6, 0, 0}, 0.01 * i);
    ASSERT_LT(Length(m - n), 1e-4);
  }
}

}  // namespace
}  // namespace nimbus
