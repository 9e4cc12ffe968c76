// Converts the chaos_game generator: the IFS, its probabilities and budget.
#include <cmath>

#include "absl/strings/str_join.h"
#include "proto/convert_internal.h"

namespace nimbus::spec::internal {

absl::StatusOr<PointMap> ConvertMap(const v1::Map& m, const std::string& path) {
  PointMap out;
  out.name = m.name();
  auto pre = ComposeSteps(m.steps(), path + ".steps");
  if (!pre.ok()) return pre.status();
  out.pre = *pre;
  for (int i = 0; i < m.variations_size(); ++i) {
    const v1::Variation& v = m.variations(i);
    const std::string vpath = StrCat(path, ".variations[", i, "]");
    const auto kind = VariationFromName(v.name());
    if (!kind) {
      std::vector<std::string> names;
      for (VariationKind k : AllVariations()) names.emplace_back(VariationName(k));
      return Invalid(vpath + ".name", StrCat("unknown variation '", v.name(),
                                             "' (known: ", absl::StrJoin(names, ", "), ")"));
    }
    NIMBUS_RETURN_IF_ERROR(CheckNumber(v.weight(), vpath + ".weight"));
    if (v.params_size() > 4) return Invalid(vpath + ".params", "at most 4 values");
    VariationTerm term;
    term.kind = *kind;
    term.weight = v.weight() == 0 ? 1.0 : v.weight();
    for (int p = 0; p < v.params_size(); ++p) {
      NIMBUS_RETURN_IF_ERROR(CheckNumber(v.params(p), StrCat(vpath, ".params[", p, "]")));
      term.params[p] = v.params(p);
    }
    out.variations.push_back(term);
  }
  if (m.post_size() > 0) {
    auto post = ComposeSteps(m.post(), path + ".post");
    if (!post.ok()) return post.status();
    out.post = *post;
  }
  if (!(m.color() >= 0 && m.color() <= 1)) return Invalid(path + ".color", "must be in [0, 1]");
  out.color = m.color();
  return out;
}

absl::Status ConvertIfs(const v1::Ifs& ifs, const std::string& path, const Limits& limits,
                        Ifs& out, JobPlan& job) {
  if (ifs.maps_size() == 0) return Invalid(path + ".maps", "needs at least one map");
  if (ifs.maps_size() > limits.max_maps)
    return absl::ResourceExhaustedError(StrCat(
        path, ".maps: ", ifs.maps_size(), " maps exceed the server limit of ", limits.max_maps));
  std::vector<std::string> expanding;
  for (int i = 0; i < ifs.maps_size(); ++i) {
    const std::string mpath = StrCat(path, ".maps[", i, "]");
    auto m = ConvertMap(ifs.maps(i), mpath);
    if (!m.ok()) return m.status();
    // For nonlinear maps the affine part's factor is only indicative.
    const double factor = m->pre.ContractionFactor();
    job.contraction_factors.push_back(factor);
    if (m->IsAffine() && factor >= 1.0) {
      char buf[64];
      std::snprintf(buf, sizeof buf, "%.4g", factor);
      expanding.push_back(StrCat(mpath, " (factor ", buf, ")"));
    }
    out.maps.push_back(std::move(*m));
  }
  if (!expanding.empty()) {
    const std::string msg =
        StrCat("not a contraction: ", absl::StrJoin(expanding, ", "),
               "; the chaos game needs every map's largest singular value below 1");
    if (!ifs.allow_expanding())
      return Invalid(path + ".maps",
                     StrCat(msg, " (set ", path, ".allow_expanding to run anyway)"));
    job.warnings.push_back(msg);
  }
  double floor = ifs.probability_floor();
  if (!(floor >= 0 && floor <= 1)) return Invalid(path + ".probability_floor", "must be in [0, 1]");
  if (floor == 0) floor = 0.01;
  for (int i = 0; i < ifs.maps_size(); ++i) {
    const double p = ifs.maps(i).probability();
    if (!(p >= 0) || !InRange(p))
      return Invalid(StrCat(path, ".maps[", i, "].probability"),
                     StrCat("must be >= 0 and at most 1e12, got ", p));
  }
  NIMBUS_RETURN_IF_ERROR(CheckProbabilityMode(ifs.probability_mode(), path + ".probability_mode"));
  v1::ProbabilityMode mode = ifs.probability_mode();
  if (mode == v1::PROBABILITY_MODE_UNSPECIFIED) {
    bool all_set = true;
    for (const auto& m : ifs.maps()) all_set &= m.probability() > 0;
    mode = all_set ? v1::PROBABILITY_MODE_EXPLICIT : v1::PROBABILITY_MODE_DETERMINANT;
  }
  if (mode == v1::PROBABILITY_MODE_EXPLICIT) {
    double total = 0;
    for (const auto& m : ifs.maps()) total += m.probability();
    if (!(total > 0)) return Invalid(path + ".maps", "explicit probabilities must not all be 0");
    for (const auto& m : ifs.maps()) out.probabilities.push_back(m.probability() / total);
  } else {
    out.probabilities = DeterminantProbabilities(out.maps, floor);
  }
  return absl::OkStatus();
}

namespace {

absl::Status ConvertFinal(const v1::Ifs& ifs, const std::string& path, Ifs& out) {
  if (ifs.has_final()) {
    auto m = ConvertMap(ifs.final(), path + ".final");
    if (!m.ok()) return m.status();
    out.final_map = std::move(*m);
  }
  if (ifs.has_arcs()) {
    const v1::Arcs& a = ifs.arcs();
    for (auto [v, name] :
         {std::pair{a.angle_per_unit(), "angle_per_unit"}, std::pair{a.amplitude(), "amplitude"},
          std::pair{a.frequency(), "frequency"}})
      NIMBUS_RETURN_IF_ERROR(CheckNumber(v, StrCat(path, ".arcs.", name)));
    out.arcs = ArcsTransform{a.angle_per_unit(), a.amplitude(), a.frequency()};
  }
  return absl::OkStatus();
}

absl::Status ConvertColor(const v1::ChaosGame& cg, ColorParams& p, DensityOptions& density) {
  if (!cg.has_color()) return absl::OkStatus();
  const v1::ChaosColor& c = cg.color();
  const std::string path = "chaos_game.color";
  switch (c.mode()) {
    case v1::COLOR_MODE_UNSPECIFIED:
    case v1::COLOR_MODE_ADDRESS:
      p.mode = ColorMode::kAddress;
      break;
    case v1::COLOR_MODE_MAP:
      p.mode = ColorMode::kMap;
      break;
    default:
      return Invalid(path + ".mode", StrCat("unknown value ", int(c.mode())));
  }
  if (!(c.blend() >= 0 && c.blend() <= 1)) return Invalid(path + ".blend", "must be in (0, 1]");
  p.blend = c.blend() == 0 ? 0.05 : c.blend();
  std::vector<PaletteStop> stops;
  for (int i = 0; i < c.palette().stops_size(); ++i) {
    const v1::PaletteStop& s = c.palette().stops(i);
    const std::string spath = StrCat(path, ".palette.stops[", i, "]");
    if (!(s.position() >= 0 && s.position() <= 1))
      return Invalid(spath + ".position", "must be in [0, 1]");
    if (i > 0 && !(s.position() >= stops.back().position))
      return Invalid(spath + ".position", "stops must be in increasing order");
    if (!Finite(s.rgb())) return Invalid(spath + ".rgb", "must be finite and within ±1e12");
    stops.push_back({s.position(), ToVec3(s.rgb())});
  }
  density.color = true;
  density.palette = stops.empty() ? Palette() : Palette(std::move(stops));
  density.address_grid = c.address_grid();
  return absl::OkStatus();
}

}  // namespace

absl::Status CheckIterations(const v1::ChaosGame& cg, const Limits& limits) {
  if (cg.iterations() == 0) return Invalid("chaos_game.iterations", "must be > 0");
  if (cg.iterations() > limits.max_iterations)
    return absl::ResourceExhaustedError(StrCat("chaos_game.iterations: ", cg.iterations(),
                                               " exceeds the server limit of ",
                                               limits.max_iterations));
  if (cg.warmup() > kMaxWarmup)
    return Invalid("chaos_game.warmup",
                   StrCat("at most ", kMaxWarmup, " steps per walker, got ", cg.warmup()));
  // Warm-up is work too: every walker of every chunk takes it (and again
  // after a re-seed), so it counts toward the iteration budget.
  const uint64_t warmup = cg.warmup() == 0 ? 100 : cg.warmup();
  const uint64_t chunks =
      (cg.iterations() + ChaosGame::kChunkIterations - 1) / ChaosGame::kChunkIterations;
  const unsigned __int128 warm = (unsigned __int128)warmup * ChaosGame::kWalkers * chunks;
  if (warm + cg.iterations() > limits.max_iterations)
    return absl::ResourceExhaustedError(StrCat(
        "chaos_game.warmup: ", uint64_t(warm), " warm-up steps (", warmup, " × ",
        ChaosGame::kWalkers, " walkers × ", chunks, " chunks) plus ", cg.iterations(),
        " iterations exceed the server limit of ", limits.max_iterations));
  return absl::OkStatus();
}

absl::Status ConvertChaosGame(const v1::ChaosGame& cg, const Limits& limits, JobPlan& job) {
  if (cg.has_matrices()) {
    if (cg.has_ifs()) return Invalid("chaos_game", "set exactly one of ifs or matrices");
    return ConvertMatrixChaosGame(cg, limits, job);
  }
  if (!cg.has_ifs()) return Invalid("chaos_game.ifs", "required (or give matrices)");
  ChaosGamePlan plan;
  ChaosGameParams& params = plan.params;
  NIMBUS_RETURN_IF_ERROR(ConvertIfs(cg.ifs(), "chaos_game.ifs", limits, params.ifs, job));
  NIMBUS_RETURN_IF_ERROR(CheckIterations(cg, limits));
  params.frame = job.frame;
  params.iterations = cg.iterations();
  params.warmup = cg.warmup() == 0 ? 100 : cg.warmup();
  params.seed = cg.seed();
  NIMBUS_RETURN_IF_ERROR(ConvertFinal(cg.ifs(), "chaos_game.ifs", params.ifs));
  NIMBUS_RETURN_IF_ERROR(ConvertEngineOptions(cg, params, job.density));
  job.work = {cg.iterations(), "points"};
  job.kind = std::move(plan);
  return absl::OkStatus();
}

absl::Status ConvertEngineOptions(const v1::ChaosGame& cg, ChaosGameParams& params,
                                  DensityOptions& density) {
  NIMBUS_RETURN_IF_ERROR(ConvertColor(cg, params.color, density));
  switch (cg.raw_counts()) {
    case v1::RAW_COUNTS_NONE:
      density.raw_counts = RawCounts::kNone;
      break;
    case v1::RAW_COUNTS_FLOAT:
      density.raw_counts = RawCounts::kFloat;
      break;
    case v1::RAW_COUNTS_UINT32:
      density.raw_counts = RawCounts::kInteger;
      break;
    default:
      return Invalid("chaos_game.raw_counts", StrCat("unknown value ", int(cg.raw_counts())));
  }
  if (cg.has_convergence()) {
    const v1::Convergence& c = cg.convergence();
    if (!(c.tolerance() > 0 && c.tolerance() <= 2))
      return Invalid("chaos_game.convergence.tolerance", "must be in (0, 2]");
    params.convergence.tolerance = c.tolerance();
    if (c.check_every() > 0) {
      const uint64_t chunk = ChaosGame::kChunkIterations;
      params.convergence.check_every = (c.check_every() + chunk - 1) / chunk * chunk;
    }
  }
  params.splat = cg.splat();
  return absl::OkStatus();
}

}  // namespace nimbus::spec::internal
