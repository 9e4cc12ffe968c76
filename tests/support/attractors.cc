#include "tests/support/attractors.h"

namespace nimbus {

namespace {
ChaosGameParams Base(int resolution, uint64_t iterations, Bounds bounds) {
  ChaosGameParams p;
  p.frame.resolution = {resolution, resolution, resolution};
  p.frame.bounds = bounds;
  p.iterations = iterations;
  p.seed = 1;
  return p;
}
}  // namespace

ChaosGameParams SierpinskiTetrahedronParams(int resolution, uint64_t iterations) {
  ChaosGameParams p = Base(resolution, iterations, {{-1, -1, -1}, {1, 1, 1}});
  const Vec3 corners[4] = {{0.5, 0.5, 0.5}, {0.5, -0.5, -0.5}, {-0.5, 0.5, -0.5},
                           {-0.5, -0.5, 0.5}};
  for (const Vec3& c : corners) {
    PointMap m;
    m.pre = Affine3::Translate(c) * Affine3::Scale({0.5, 0.5, 0.5});
    p.ifs.maps.push_back(m);
  }
  p.ifs.probabilities = DeterminantProbabilities(p.ifs.maps, 0.01);
  return p;
}

ChaosGameParams OctantCloudParams(int resolution, uint64_t iterations) {
  ChaosGameParams p = Base(resolution, iterations, {{-1.2, -1.2, -1.2}, {1.2, 1.2, 1.2}});
  for (int i = 0; i < 8; ++i) {
    PointMap m;
    const Vec3 o{(i & 1) ? 0.5 : -0.5, (i & 2) ? 0.5 : -0.5, (i & 4) ? 0.5 : -0.5};
    m.pre = Affine3::Translate(o) * Affine3::Rotate({1, 1, 1}, 7.0 * i) *
            Affine3::Scale({0.5, 0.5, 0.5});
    p.ifs.maps.push_back(m);
  }
  p.ifs.probabilities.assign(8, 1.0 / 8);
  return p;
}

ChaosGameParams FernVolumeParams(int resolution, uint64_t iterations) {
  ChaosGameParams p = Base(resolution, iterations, {{-5.4, -0.2, -5.4}, {5.4, 10.6, 5.4}});
  const Vec3 y{0, 1, 0}, z{0, 0, 1};
  PointMap frond;  // the whole fern, shrunk, twisted and lifted
  frond.pre = Affine3::Translate({0, 1.6, 0}) * Affine3::Rotate(y, 25) *
              Affine3::Rotate(z, -2.5) * Affine3::Scale({0.85, 0.85, 0.85});
  p.ifs.maps.push_back(frond);
  for (int j = 0; j < 4; ++j) {  // four leaflets around the stem
    PointMap leaf;
    leaf.pre = Affine3::Translate({0, 0.6 + 0.25 * j, 0}) * Affine3::Rotate(y, 90.0 * j) *
               Affine3::Rotate(z, 50) * Affine3::Scale({0.48, 0.48, 0.48});
    p.ifs.maps.push_back(leaf);
  }
  PointMap stem;
  stem.pre = Affine3::Scale({0.06, 0.16, 0.06});
  p.ifs.maps.push_back(stem);
  p.ifs.probabilities = DeterminantProbabilities(p.ifs.maps, 0.01);
  return p;
}

}  // namespace nimbus
