#include "core/chaos/auto_frame.h"

#include <algorithm>
#include <vector>

namespace nimbus {

absl::StatusOr<Bounds> FitBounds(const ChaosGameParams& p, const AutoFrameParams& fit,
                                 Interrupter* interrupter) {
  if (p.ifs.maps.empty() || p.ifs.probabilities.size() != p.ifs.maps.size())
    return absl::InvalidArgumentError("auto-framing needs an IFS with probabilities");
  Interrupter& intr = OrNull(interrupter);
  const AliasTable table(p.ifs.probabilities);
  const int walkers = ChaosGame::kWalkers;
  const uint64_t per = (fit.pilot_iterations + walkers - 1) / walkers;
  std::vector<double> axis[3];
  for (auto& a : axis) a.reserve(per * walkers);
  const Bounds& b = p.frame.bounds;
  for (int k = 0; k < walkers; ++k) {
    // Its own stream, apart from every chunk's walkers (seed, chunk * 16 + k).
    Rng rng(p.seed ^ 0x6175746f6672616dULL, uint64_t(k));
    auto start = [&] {
      return Vec3{rng.Uniform(b.min.x, b.max.x), rng.Uniform(b.min.y, b.max.y),
                  rng.Uniform(b.min.z, b.max.z)};
    };
    Vec3 pos = start();
    for (uint64_t j = 0; j < per + p.warmup; ++j) {
      if ((j & 0xffff) == 0 && intr.WasInterrupted(uint64_t(k) * per, per * walkers))
        return absl::CancelledError("interrupted");
      pos = p.ifs.maps[table.Sample(rng.Next())].Apply(pos, rng);
      if (!IsFinite(pos)) {
        pos = start();
        continue;
      }
      if (j < p.warmup) continue;
      Vec3 q = p.ifs.final_map ? p.ifs.final_map->Apply(pos, rng) : pos;
      if (p.ifs.arcs) q = p.ifs.arcs->Apply(q, (j - p.warmup) * walkers + uint64_t(k));
      if (!IsFinite(q)) continue;
      for (int a = 0; a < 3; ++a) axis[a].push_back(q[a]);
    }
  }
  if (axis[0].empty()) return absl::FailedPreconditionError("the pilot plotted no finite point");
  Bounds out;
  double largest = 0;
  for (int a = 0; a < 3; ++a) {
    std::vector<double>& v = axis[a];
    const size_t cut = std::min(v.size() - 1, size_t(double(v.size()) * fit.trim));
    std::nth_element(v.begin(), v.begin() + cut, v.end());
    out.min[a] = v[cut];
    std::nth_element(v.begin(), v.end() - 1 - cut, v.end());
    out.max[a] = v[v.size() - 1 - cut];
    largest = std::max(largest, out.max[a] - out.min[a]);
  }
  if (!(largest > 0)) largest = 1;
  for (int a = 0; a < 3; ++a) {
    double lo = out.min[a], hi = out.max[a];
    const double floor = largest * 1e-3;
    if (hi - lo < floor) {
      const double c = 0.5 * (lo + hi);
      lo = c - floor / 2, hi = c + floor / 2;
    }
    const double m = fit.margin * (hi - lo);
    out.min[a] = lo - m;
    out.max[a] = hi + m;
  }
  return out;
}

}  // namespace nimbus
