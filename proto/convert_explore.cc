// Converts the explore generator (docs/explore.md): the random IFS drawn,
// the contraction test, thumbnails, the sheet, and the template of the
// candidates' specs. Every range is checked before anything is allocated.
#include <cmath>

#include "absl/strings/str_join.h"
#include "proto/convert_internal.h"

namespace nimbus::spec::internal {

namespace {

constexpr int kMaxCount = 1024;
constexpr int kMaxMapsPerIfs = 16;
constexpr uint64_t kMaxAttempts = 10'000'000;
constexpr uint64_t kMinThumbIterations = uint64_t{1} << 16;
constexpr uint64_t kMaxThumbIterations = uint64_t{1} << 28;
// Thumbnail pixels of one sheet (about 400 MB of float RGB at most).
constexpr int64_t kMaxSheetPixels = int64_t{1} << 25;

// `v` (0: `def`) within [lo, hi]; an integer field.
absl::StatusOr<int64_t> IntOr(int64_t v, int64_t def, int64_t lo, int64_t hi,
                              const std::string& path) {
  if (v == 0) return def;
  if (v < lo || v > hi) return Invalid(path, StrCat("must be in [", lo, ", ", hi, "], got ", v));
  return v;
}

// `v` (0: `def`) within (lo, hi] (open below) or [lo, hi].
absl::StatusOr<double> RealOr(double v, double def, double lo, double hi, bool open_low,
                              const std::string& path) {
  NIMBUS_RETURN_IF_ERROR(CheckNumber(v, path));
  if (v == 0) return def;
  if (!((open_low ? v > lo : v >= lo) && v <= hi))
    return Invalid(path, StrCat("must be in ", open_low ? "(" : "[", lo, ", ", hi, "], got ", v));
  return v;
}

absl::Status ConvertDraw(const v1::Explore& e, RandomIfsParams& d) {
  const std::string path = "explore";
  NIMBUS_ASSIGN_OR_RETURN(int64_t dims, IntOr(e.dimensions(), 2, 2, 3, path + ".dimensions"));
  d.dimensions = int(dims);
  NIMBUS_ASSIGN_OR_RETURN(int64_t lo,
                          IntOr(e.min_maps(), 3, 2, kMaxMapsPerIfs, path + ".min_maps"));
  NIMBUS_ASSIGN_OR_RETURN(int64_t hi, IntOr(e.max_maps(), std::max<int64_t>(lo, 5), 2,
                                            kMaxMapsPerIfs, path + ".max_maps"));
  if (hi < lo)
    return Invalid(path + ".max_maps", StrCat("must be at least explore.min_maps (", lo,
                                              "), got ", hi));
  d.min_maps = int(lo), d.max_maps = int(hi);
  NIMBUS_ASSIGN_OR_RETURN(d.coefficient_range, RealOr(e.coefficient_range(), dims == 3 ? 0.6 : 1,
                                                      0, 2, true, path + ".coefficient_range"));
  NIMBUS_ASSIGN_OR_RETURN(d.translation_range, RealOr(e.translation_range(), 1, 0, 10, true,
                                                      path + ".translation_range"));
  for (int i = 0; i < e.variations_size(); ++i) {
    const std::string vpath = StrCat(path, ".variations[", i, "]");
    const auto kind = VariationFromName(e.variations(i));
    if (!kind) {
      std::vector<std::string> names;
      for (VariationKind k : AllVariations())
        if (GetVariationInfo(k).param_count == 0) names.emplace_back(VariationName(k));
      return Invalid(vpath, StrCat("unknown variation '", e.variations(i),
                                   "' (known: ", absl::StrJoin(names, ", "), ")"));
    }
    if (GetVariationInfo(*kind).param_count > 0)
      return Invalid(vpath, StrCat("'", e.variations(i),
                                   "' takes parameters; the explorer draws parameter-free "
                                   "variations only"));
    d.variations.push_back(*kind);
  }
  NIMBUS_RETURN_IF_ERROR(CheckNumber(e.variation_probability(), path + ".variation_probability"));
  if (!(e.variation_probability() >= 0 && e.variation_probability() <= 1))
    return Invalid(path + ".variation_probability",
                   StrCat("must be in [0, 1], got ", e.variation_probability()));
  if (e.variation_probability() > 0 && d.variations.empty())
    return Invalid(path + ".variation_probability", "needs explore.variations");
  d.variation_probability = e.variation_probability() == 0 ? 0.5 : e.variation_probability();
  return absl::OkStatus();
}

absl::Status ConvertTest(const v1::Explore& e, ExploreParams& p) {
  const std::string path = "explore";
  switch (e.measure()) {
    case v1::CONTRACTION_MEASURE_UNSPECIFIED:
    case v1::CONTRACTION_MEASURE_SINGULAR_VALUE: {
      p.measure = ContractionMeasure::kSingularValue;
      NIMBUS_ASSIGN_OR_RETURN(p.threshold,
                              RealOr(e.threshold(), 0.9, 0, 1, true, path + ".threshold"));
      break;
    }
    case v1::CONTRACTION_MEASURE_DETERMINANT: {
      p.measure = ContractionMeasure::kDeterminant;
      NIMBUS_ASSIGN_OR_RETURN(p.threshold,
                              RealOr(e.threshold(), 1.5, 0, 16, true, path + ".threshold"));
      break;
    }
    default:
      return Invalid(path + ".measure",
                     StrCat("unknown value ", int(e.measure()),
                            " (known: CONTRACTION_MEASURE_SINGULAR_VALUE, "
                            "CONTRACTION_MEASURE_DETERMINANT)"));
  }
  NIMBUS_ASSIGN_OR_RETURN(int64_t count, IntOr(e.count(), 16, 1, kMaxCount, path + ".count"));
  p.count = int(count);
  const uint64_t def_attempts = std::min<uint64_t>(10'000 * uint64_t(count), kMaxAttempts);
  if (e.max_attempts() != 0 && (e.max_attempts() < uint64_t(count) ||
                                e.max_attempts() > kMaxAttempts))
    return Invalid(path + ".max_attempts", StrCat("must be in [explore.count = ", count, ", ",
                                                  kMaxAttempts, "], got ", e.max_attempts()));
  p.max_attempts = e.max_attempts() == 0 ? def_attempts : e.max_attempts();
  NIMBUS_RETURN_IF_ERROR(CheckNumber(e.min_coverage(), path + ".min_coverage"));
  if (!(e.min_coverage() >= 0 && e.min_coverage() <= 0.5))
    return Invalid(path + ".min_coverage", StrCat("must be in [0, 0.5], got ", e.min_coverage()));
  p.min_coverage = e.min_coverage() == 0 ? 0.06 : e.min_coverage();
  return absl::OkStatus();
}

absl::Status ConvertThumbnails(const v1::Explore& e, const Limits& limits, ExplorePlan& plan) {
  const std::string path = "explore";
  ExploreParams& p = plan.params;
  NIMBUS_ASSIGN_OR_RETURN(int64_t size,
                          IntOr(e.thumbnail_size(), 256, 16, 1024, path + ".thumbnail_size"));
  p.thumbnail_size = int(size);
  if (int64_t(p.count) * size * size > kMaxSheetPixels)
    return absl::ResourceExhaustedError(
        StrCat(path, ".count: ", p.count, " thumbnails of ", size, " x ", size,
               " pixels exceed the contact sheet's limit of ", kMaxSheetPixels,
               " pixels; lower explore.count or explore.thumbnail_size"));
  const uint64_t it = e.thumbnail_iterations();
  if (it != 0 && (it < kMinThumbIterations || it > kMaxThumbIterations))
    return Invalid(path + ".thumbnail_iterations",
                   StrCat("must be in [", kMinThumbIterations, ", ", kMaxThumbIterations,
                          "], got ", it));
  p.thumbnail_iterations = it == 0 ? uint64_t{1} << 21 : it;
  if (p.thumbnail_iterations * uint64_t(p.count) > limits.max_iterations)
    return absl::ResourceExhaustedError(
        StrCat(path, ".thumbnail_iterations: ", p.thumbnail_iterations, " x ", p.count,
               " thumbnails exceed the server limit of ", limits.max_iterations, " iterations"));
  if (e.columns() < 0 || e.columns() > 64)
    return Invalid(path + ".columns", StrCat("must be in [1, 64] or 0 (automatic), got ",
                                             e.columns()));
  plan.columns = e.columns();
  NIMBUS_RETURN_IF_ERROR(CheckNumber(e.color_blend(), path + ".color_blend"));
  if (!(e.color_blend() >= 0 && e.color_blend() <= 1))
    return Invalid(path + ".color_blend", StrCat("must be in (0, 1], got ", e.color_blend()));
  p.color = {ColorMode::kAddress, e.color_blend() == 0 ? 0.5 : e.color_blend()};
  return absl::OkStatus();
}

// The look the explorer uses when the spec gives none: the seed picture's.
v1::Look DefaultLook() {
  v1::Look l;
  l.set_desaturation(30);
  l.set_glow(50);
  l.set_brightness(1.5);
  return l;
}

// A candidate's spec without its maps, seed and box.
absl::Status MakeTemplate(const v1::Explore& e, const v1::Look& look, const ExploreParams& p,
                          ExplorePlan& plan) {
  const std::string path = "explore.candidate";
  const v1::ExploreCandidateSpec& c = e.candidate();
  NIMBUS_ASSIGN_OR_RETURN(int64_t width, IntOr(c.width(), 1024, 16, 16384, path + ".width"));
  NIMBUS_ASSIGN_OR_RETURN(int64_t ss, IntOr(c.supersample(), 2, 1, 4, path + ".supersample"));
  NIMBUS_ASSIGN_OR_RETURN(int64_t res, IntOr(c.resolution(), 256, 16, 4096, path + ".resolution"));
  const uint64_t it = c.iterations() == 0 ? 100'000'000 : c.iterations();
  if (it < (uint64_t{1} << 20) || it > 1'000'000'000'000)
    return Invalid(path + ".iterations",
                   StrCat("must be in [1048576, 1000000000000], got ", c.iterations()));
  const bool solid = p.draw.dimensions == 3;
  v1::JobSpec t;
  v1::Grid& g = *t.mutable_grid();
  g.add_resolution(int(res));
  g.add_resolution(int(res));
  g.add_resolution(solid ? int(res) : 1);
  v1::ChaosGame& cg = *t.mutable_chaos_game();
  cg.mutable_ifs()->set_probability_mode(v1::PROBABILITY_MODE_DETERMINANT);
  cg.set_iterations(it);
  cg.mutable_color()->set_mode(v1::COLOR_MODE_ADDRESS);
  cg.mutable_color()->set_blend(p.color.blend);
  v1::ImageOutput& im = *t.mutable_image();
  im.set_width(int(width));
  im.set_supersample(int(ss));
  im.set_image_only(!solid);
  *im.mutable_look() = look;
  if (solid) t.mutable_output()->set_density_mapping(v1::DENSITY_MAPPING_SQRT);
  // The template must convert once it has maps: check it now, with one map.
  v1::JobSpec probe = t;
  v1::Map& m = *probe.mutable_chaos_game()->mutable_ifs()->add_maps();
  m.add_steps()->mutable_scale()->set_uniform(0.5);
  Limits lim;
  if (auto s = ConvertSpec(probe, lim); !s.ok())
    return Invalid(path, StrCat("gives an invalid spec: ", s.status().message()));
  plan.candidate_template = t.SerializeAsString();
  return absl::OkStatus();
}

}  // namespace

absl::Status ConvertExplore(const v1::Explore& e, const Limits& limits, JobPlan& job) {
  ExplorePlan plan;
  ExploreParams& p = plan.params;
  NIMBUS_RETURN_IF_ERROR(ConvertDraw(e, p.draw));
  NIMBUS_RETURN_IF_ERROR(ConvertTest(e, p));
  NIMBUS_RETURN_IF_ERROR(ConvertThumbnails(e, limits, plan));
  p.seed = e.seed();
  const v1::Look look = e.has_look() ? e.look() : DefaultLook();
  bool default_glow_radius = true;
  NIMBUS_RETURN_IF_ERROR(ConvertLook(look, "explore.look", p.look, &default_glow_radius));
  NIMBUS_RETURN_IF_ERROR(MakeTemplate(e, look, p, plan));
  // The glow is sized on the candidate's picture: 1 % of its width by
  // default, or the given pixels scaled down to the thumbnail.
  const int width = e.candidate().width() == 0 ? 1024 : e.candidate().width();
  p.look.glow_radius = default_glow_radius
                           ? 0.01 * p.thumbnail_size
                           : p.look.glow_radius * double(p.thumbnail_size) / double(width);
  p.look.colored = true;
  job.work = {uint64_t(p.count), "thumbnails"};
  job.kind = std::move(plan);
  return absl::OkStatus();
}

}  // namespace nimbus::spec::internal
