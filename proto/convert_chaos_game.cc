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
      return Invalid(vpath + ".name", StrCat("unknown variation '", v.name(), "' (known: ",
                                             absl::StrJoin(names, ", "), ")"));
    }
    if (!std::isfinite(v.weight())) return Invalid(vpath + ".weight", "must be finite");
    if (v.params_size() > 4) return Invalid(vpath + ".params", "at most 4 values");
    VariationTerm term;
    term.kind = *kind;
    term.weight = v.weight() == 0 ? 1.0 : v.weight();
    for (int p = 0; p < v.params_size(); ++p) {
      if (!std::isfinite(v.params(p)))
        return Invalid(StrCat(vpath, ".params[", p, "]"), "must be finite");
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
                        ConvertedJob& job) {
  Ifs& out = job.chaos_game.ifs;
  if (ifs.maps_size() == 0) return Invalid(path + ".maps", "needs at least one map");
  if (ifs.maps_size() > limits.max_maps)
    return absl::ResourceExhaustedError(StrCat(path, ".maps: ", ifs.maps_size(),
                                               " maps exceed the server limit of ",
                                               limits.max_maps));
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
      return Invalid(path + ".maps", StrCat(msg, " (set ", path, ".allow_expanding to run anyway)"));
    job.warnings.push_back(msg);
  }
  double floor = ifs.probability_floor();
  if (!(floor >= 0 && floor <= 1)) return Invalid(path + ".probability_floor", "must be in [0, 1]");
  if (floor == 0) floor = 0.01;
  for (int i = 0; i < ifs.maps_size(); ++i) {
    const double p = ifs.maps(i).probability();
    if (!(p >= 0) || !std::isfinite(p))
      return Invalid(StrCat(path, ".maps[", i, "].probability"), "must be finite and >= 0");
  }
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


absl::Status ConvertChaosGame(const v1::ChaosGame& cg, const Limits& limits, int threads,
                              ConvertedJob& job) {
  if (cg.has_matrices()) {
    if (cg.has_ifs()) return Invalid("chaos_game", "set exactly one of ifs or matrices");
    return ConvertMatrixChaosGame(cg, limits, threads, job);
  }
  job.generator = Generator::kChaosGame;
  if (!cg.has_ifs()) return Invalid("chaos_game.ifs", "required (or give matrices)");
  if (auto st = ConvertIfs(cg.ifs(), "chaos_game.ifs", limits, job); !st.ok()) return st;
  if (cg.iterations() == 0) return Invalid("chaos_game.iterations", "must be > 0");
  if (cg.iterations() > limits.max_iterations)
    return absl::ResourceExhaustedError(StrCat("chaos_game.iterations: ", cg.iterations(),
                                               " exceeds the server limit of ",
                                               limits.max_iterations));
  job.chaos_game.frame = job.frame;
  job.chaos_game.iterations = cg.iterations();
  job.chaos_game.warmup = cg.warmup() == 0 ? 100 : cg.warmup();
  job.chaos_game.seed = cg.seed();
  job.total_work = cg.iterations();
  job.estimated_memory_bytes = ChaosGame::EstimateMemoryBytes(job.frame.resolution, threads);
  return absl::OkStatus();
}

}  // namespace nimbus::spec::internal
