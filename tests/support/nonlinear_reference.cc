#include "tests/support/nonlinear_reference.h"

#include <algorithm>
#include <cmath>
#include <complex>
#include <numbers>
#include <vector>

namespace nimbus::testing {
namespace {

constexpr double kPi = std::numbers::pi;
constexpr double kGuard = 1e-10;  // docs/variations.md: eps

// Random words one evaluation of a variation reads (docs/variations.md):
// julia one (its top bit), blur and noise three uniforms.
int Words(VariationKind kind) {
  switch (kind) {
    case VariationKind::kJulia:
      return 1;
    case VariationKind::kBlur:
    case VariationKind::kNoise:
      return 3;
    default:
      return 0;
  }
}

int MapWords(const PointMap& map) {
  int n = 0;
  for (const VariationTerm& t : map.variations) n += Words(t.kind);
  return n;
}

// `words` holds the map's words, each term reading its own in turn.
Vec3 Apply(const MapRule rule, const PointMap& map, Vec3 p, const uint64_t* words) {
  const Vec3 q = map.pre.Apply(p);
  if (rule == MapRule::kAffineOnly) return q;
  Vec3 s = q;
  if (!map.variations.empty()) {
    s = Vec3{};
    for (const VariationTerm& t : map.variations) {
      WordCursor cursor{words};
      const Vec3 v = rule == MapRule::kEngineVariations ? EvaluateVariation(t, q, map.pre, words)
                                                        : DocsVariation(t.kind, q, cursor);
      s = s + t.weight * v;
      words += Words(t.kind);
    }
  }
  return map.post ? map.post->Apply(s) : s;
}

// Uniform direction from two draws, as blur and noise document it.
Vec3 DocsDirection(WordCursor& rng) {
  const double cos_polar = 2 * rng.Uniform() - 1;
  const double azimuth = 2 * kPi * rng.Uniform();
  const double sin_polar = std::sqrt(std::max(0.0, 1 - cos_polar * cos_polar));
  return {sin_polar * std::cos(azimuth), sin_polar * std::sin(azimuth), cos_polar};
}

// One walker: its stream, position and colour coordinates, and the words
// of its last step.
struct Walker {
  const ChaosGameParams& p;
  const AliasTable& table;
  MapRule rule;
  Rng rng;
  std::vector<uint64_t> words;  // drawn afresh every step
  size_t final_word = 0;
  Vec3 pos;
  double addr = 0, col = 0;

  bool Step() {
    for (uint64_t& w : words) w = rng.Next();
    const uint32_t m = table.Sample(words[0]);
    pos = Apply(rule, p.ifs.maps[m], pos, words.data() + 1);
    if (p.color.mode != ColorMode::kNone) {
      addr = (double(m) + addr) * (1.0 / double(p.ifs.maps.size()));
      const double target = p.color.mode == ColorMode::kAddress ? addr : p.ifs.maps[m].color;
      col += p.color.blend * (target - col);
    }
    return IsFinite(pos);
  }
  void Seed() {
    const Bounds& b = p.frame.bounds;
    const double x = rng.Uniform(b.min.x, b.max.x);
    const double y = rng.Uniform(b.min.y, b.max.y);
    pos = {x, y, rng.Uniform(b.min.z, b.max.z)};
  }
  // Returns the re-seeds it needed.
  uint64_t Restart() {
    Seed();
    if (p.color.mode != ColorMode::kNone) addr = col = rng.Uniform();
    uint64_t reseeds = 0;
    for (uint32_t i = 0; i < p.warmup; ++i)
      if (!Step()) {
        Seed();
        ++reseeds;
      }
    return reseeds;
  }
};

void Plot(Walker& w, NonlinearReferenceRun& run) {
  const ChaosGameParams& p = w.p;
  Vec3 q = w.pos;
  if (p.ifs.final_map) {
    q = Apply(w.rule == MapRule::kAffineOnly ? MapRule::kEngineVariations : w.rule,
              *p.ifs.final_map, q, w.words.data() + w.final_word);
    if (!IsFinite(q)) {
      ++run.final_nonfinite;
      ++run.outside;
      return;
    }
  }
  const Bounds& b = p.frame.bounds;
  const Vec3 h = p.frame.VoxelSize();
  const Int3 r = p.frame.resolution;
  const double u[3] = {(q.x - b.min.x) * (1.0 / h.x), (q.y - b.min.y) * (1.0 / h.y),
                       (q.z - b.min.z) * (1.0 / h.z)};
  for (int a = 0; a < 3; ++a)
    if (!(u[a] >= 0 && u[a] < r[a])) {  // NaN lands here too
      ++run.outside;
      return;
    }
  ReferenceVoxel& v = run.voxels[run.VoxelIndex(int(u[0]), int(u[1]), int(u[2]))];
  ++v.count;
  if (p.color.mode != ColorMode::kNone)
    v.color_sum += uint64_t(std::clamp(w.col, 0.0, 1.0) * CountGrid::kColorScale + 0.5);
}

}  // namespace

ReferenceVoxel NonlinearReferenceRun::At(int x, int y, int z) const {
  const auto it = voxels.find(VoxelIndex(x, y, z));
  return it == voxels.end() ? ReferenceVoxel{} : it->second;
}

uint64_t NonlinearReferenceRun::Total() const {
  uint64_t total = 0;
  for (const auto& [index, v] : voxels) total += v.count;
  return total;
}

bool HasDocsVariation(VariationKind kind) {
  switch (kind) {
    case VariationKind::kLinear:
    case VariationKind::kSinusoidal:
    case VariationKind::kSpherical:
    case VariationKind::kSwirl:
    case VariationKind::kJulia:
    case VariationKind::kBubble:
    case VariationKind::kBlur:
    case VariationKind::kNoise:
    case VariationKind::kPolarDoubling:
      return true;
    default:
      return false;
  }
}

Vec3 DocsVariation(VariationKind kind, Vec3 q, WordCursor& rng) {
  const std::complex<double> w(q.x, q.y);
  const double r2 = Dot(q, q), rho2 = std::norm(w);
  switch (kind) {
    case VariationKind::kLinear:
      return q;
    case VariationKind::kSinusoidal:
      return {std::sin(q.x), std::sin(q.y), std::sin(q.z)};
    case VariationKind::kSpherical:
      return (1 / (r2 + kGuard)) * q;
    case VariationKind::kSwirl:
      return {q.x * std::sin(rho2) - q.y * std::cos(rho2),
              q.x * std::cos(rho2) + q.y * std::sin(rho2), q.z};
    case VariationKind::kJulia: {
      const double omega = (rng.Next() >> 63) ? kPi : 0.0;
      const std::complex<double> root =
          std::polar(std::sqrt(std::abs(w)), 0.5 * std::atan2(q.x, q.y) + omega);  // flam3's angle
      return {root.real(), root.imag(), q.z};
    }
    case VariationKind::kBubble:
      return (4 / (r2 + 4)) * q;
    case VariationKind::kBlur: {
      const Vec3 d = DocsDirection(rng);
      return std::cbrt(rng.Uniform()) * d;
    }
    case VariationKind::kNoise: {
      const Vec3 d = DocsDirection(rng);
      const double s = rng.Uniform();
      return {s * q.x * d.x, s * q.y * d.y, s * q.z * d.z};
    }
    case VariationKind::kPolarDoubling: {
      const std::complex<double> v = std::polar(std::abs(w) / std::sqrt(2.0), 2 * std::arg(w));
      return {v.real(), v.imag(), q.z / std::sqrt(2.0)};
    }
    default:
      return {std::nan(""), std::nan(""), std::nan("")};  // not implemented here
  }
}

absl::StatusOr<NonlinearReferenceRun> RunNonlinearReference(const ChaosGameParams& params,
                                                            MapRule rule) {
  if (params.chain || params.ifs.arcs || params.splat)
    return absl::InvalidArgumentError("reference: chains, arcs and splatting are not modelled");
  if (rule == MapRule::kDocsVariations) {
    auto check = [](const PointMap& m) {
      return std::all_of(m.variations.begin(), m.variations.end(),
                         [](const VariationTerm& t) { return HasDocsVariation(t.kind); });
    };
    bool ok = std::all_of(params.ifs.maps.begin(), params.ifs.maps.end(), check);
    if (params.ifs.final_map) ok = ok && check(*params.ifs.final_map);
    if (!ok) return absl::InvalidArgumentError("reference: a variation has no docs formula here");
  }
  const AliasTable table(params.ifs.probabilities);
  NonlinearReferenceRun run{params.frame.resolution, {}, 0, 0, 0};
  constexpr uint64_t kChunk = ChaosGame::kChunkIterations;
  // Words per step: one for the map, the most any map reads, the final
  // transform's. Walkers per chunk: 16 for affine maps whose final
  // transform draws nothing, 64 otherwise (docs/chaos_game.md).
  int map_words = 0;
  for (const PointMap& m : params.ifs.maps) map_words = std::max(map_words, MapWords(m));
  const int final_words = params.ifs.final_map ? MapWords(*params.ifs.final_map) : 0;
  const bool affine = params.ifs.AllAffine() && final_words == 0;
  const uint64_t kW = affine ? 16 : 64;
  for (uint64_t chunk = 0; chunk * kChunk < params.iterations; ++chunk) {
    const uint64_t count = std::min(kChunk, params.iterations - chunk * kChunk);
    for (uint64_t k = 0; k < kW; ++k) {
      Walker w{params, table, rule, Rng(params.seed, chunk * kW + k),
               std::vector<uint64_t>(size_t(1 + map_words + final_words)),
               size_t(1 + map_words), {}};
      run.reseeded += w.Restart();
      for (uint64_t i = k; i < count; i += kW) {
        if (!w.Step()) {
          run.reseeded += 1 + w.Restart();
          continue;
        }
        Plot(w, run);
      }
    }
  }
  return run;
}

}  // namespace nimbus::testing
