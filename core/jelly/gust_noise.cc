#include "core/jelly/gust_noise.h"

#include <cmath>

#include "core/base/random.h"

namespace nimbus {

namespace {

double Smooth(double f) { return f * f * (3 - 2 * f); }

// A lattice value in [-1, 1] for component `c`.
double Node(uint64_t seed, int64_t x, int64_t y, int64_t z, int64_t t, int c) {
  const uint64_t h = HashCoords(seed, uint64_t(x), uint64_t(y), uint64_t(z), uint64_t(t),
                                uint64_t(c));
  return double(h >> 11) * 0x1.0p-52 - 1.0;
}

}  // namespace

Vec3 GustNoise(uint64_t seed, Vec3 p, double t) {
  const double q[4] = {p.x, p.y, p.z, t};
  int64_t i[4];
  double w[4];
  for (int a = 0; a < 4; ++a) {
    const double f = std::floor(q[a]);
    i[a] = int64_t(f);
    w[a] = Smooth(q[a] - f);
  }
  Vec3 out;
  for (int corner = 0; corner < 16; ++corner) {
    double weight = 1;
    int64_t c[4];
    for (int a = 0; a < 4; ++a) {
      const int bit = (corner >> a) & 1;
      c[a] = i[a] + bit;
      weight *= bit ? w[a] : 1 - w[a];
    }
    for (int comp = 0; comp < 3; ++comp)
      out[comp] += weight * Node(seed, c[0], c[1], c[2], c[3], comp);
  }
  return out;
}

}  // namespace nimbus
