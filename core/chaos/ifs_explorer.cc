#include "core/chaos/ifs_explorer.h"

#include <algorithm>
#include <cmath>

#include "core/base/status_macros.h"

namespace nimbus {

namespace {

// A framed box larger than this (or not finite) means the walk escaped.
constexpr double kMaxBoxSide = 1e6;

bool SaneBox(const Bounds& b) {
  for (int a = 0; a < 3; ++a)
    if (!(std::isfinite(b.min[a]) && std::isfinite(b.max[a]) && b.max[a] > b.min[a] &&
          b.max[a] - b.min[a] < kMaxBoxSide))
      return false;
  return true;
}

// The chaos game of candidate `attempt` before framing.
ChaosGameParams CandidateParams(const ExploreParams& p, std::vector<PointMap> maps,
                                uint64_t attempt) {
  ChaosGameParams g;
  g.ifs.probabilities = DeterminantProbabilities(maps, 0.01);
  g.ifs.maps = std::move(maps);
  g.frame.bounds = ExploreStartBox(p.draw);
  g.frame.resolution = {p.thumbnail_size, p.thumbnail_size, 1};
  g.iterations = p.thumbnail_iterations;
  g.warmup = kExploreWarmup;
  g.seed = attempt;
  g.color = p.color;
  g.memory_budget = p.memory_budget;
  return g;
}

// Counts the thumbnail of `c` and box-filters it to pixels (1:1).
absl::StatusOr<ImageDensity> CountThumbnail(const ExploreParams& p, const ExploreCandidate& c,
                                            int threads, Interrupter* interrupter) {
  ChaosGameParams g = c.params;
  // Along -z (solid IFS come turned, core/chaos/random_ifs.h), framing the
  // fitted box.
  g.image = MakeImagePlane(ImageView{}, g.frame.bounds, p.thumbnail_size, p.thumbnail_size);
  NIMBUS_ASSIGN_OR_RETURN(auto game, ChaosGame::Create(std::move(g), threads));
  NIMBUS_RETURN_IF_ERROR(game->Run(interrupter));
  const CountGrid counts = game->TakeCounts();
  return BoxFilterImage({&counts}, p.thumbnail_size, p.thumbnail_size, 1, 1, interrupter);
}

double Coverage(const ImageDensity& d) {
  size_t lit = 0;
  for (float v : d.density) lit += v > 0;
  return d.density.empty() ? 0 : double(lit) / double(d.density.size());
}

}  // namespace

Bounds ExploreStartBox(const RandomIfsParams& draw) {
  const double s = draw.translation_range;
  const double z = draw.dimensions == 3 ? s : 0.1 * s;
  return {{-s, -s, -z}, {s, s, z}};
}

absl::StatusOr<ExploreStats> ExploreIfs(const ExploreParams& p, int threads,
                                        Interrupter* interrupter, const ExploreSink& sink) {
  Interrupter& intr = OrNull(interrupter);
  ExploreStats stats;
  const int dims = p.draw.dimensions;
  while (stats.kept < uint64_t(p.count) && stats.attempts < p.max_attempts) {
    const uint64_t attempt = stats.attempts++;
    // Drawing and testing is about a microsecond: poll now and then.
    if ((attempt & 1023) == 0 && intr.WasInterrupted(stats.kept, uint64_t(p.count)))
      return absl::CancelledError("interrupted");
    std::vector<PointMap> maps = DrawRandomIfs(p.draw, p.seed, attempt);
    const double contraction = IfsContraction(maps, dims, p.measure);
    if (!(contraction < p.threshold)) continue;
    ++stats.contractive;
    ExploreCandidate c;
    c.attempt = attempt;
    c.contraction = contraction;
    c.params = CandidateParams(p, std::move(maps), attempt);
    auto box = FitBounds(c.params, p.frame, interrupter);
    if (!box.ok() && absl::IsCancelled(box.status())) return box.status();
    if (!box.ok() || !SaneBox(*box)) continue;
    c.params.frame.bounds = *box;
    NIMBUS_ASSIGN_OR_RETURN(ImageDensity density, CountThumbnail(p, c, threads, interrupter));
    c.coverage = Coverage(density);
    if (c.coverage < p.min_coverage) continue;
    LookParams look = p.look;
    look.colored = p.color.mode != ColorMode::kNone;
    NIMBUS_ASSIGN_OR_RETURN(RgbImage thumb, DevelopImage(density, look, interrupter));
    ++stats.kept;
    NIMBUS_RETURN_IF_ERROR(sink(c, std::move(thumb)));
  }
  return stats;
}

}  // namespace nimbus
