#include "tests/support/jelly_scenes.h"

namespace nimbus::testing {

JellyPlan SierpinskiJelly(uint32_t depth) {
  JellyPlan p;
  const Vec3 v[4] = {{0, 2.18, 0}, {0.69, 1.2, 0}, {-0.35, 1.2, 0.6}, {-0.35, 1.2, -0.6}};
  for (const Vec3& c : v) {
    JellyBody b;
    b.scale = {0.5, 0.5, 0.5};
    b.position = 0.5 * c;
    b.radius = 0.04;
    p.sim.bodies.push_back(b);
  }
  for (int i = 0; i < 4; ++i)
    for (int j = i + 1; j < 4; ++j)
      p.sim.springs.push_back(
          {i, j, {}, Length(p.sim.bodies[i].position - p.sim.bodies[j].position), 60, 0.6});
  p.sim.ground = {true, 0, 0.2, 0.6};
  p.sim.collisions = true;
  p.fps = 24;
  p.substeps = 10;
  p.sim.dt = 1.0 / 240;
  p.frames = 48;
  p.render.depth = depth;
  return p;
}

}  // namespace nimbus::testing
