#include "proto/explore_candidate.h"

#include <string>

#include "absl/strings/str_cat.h"

namespace nimbus::spec {

namespace {

void SetVec3(const Vec3& v, v1::Vec3* out) {
  out->set_x(v.x);
  out->set_y(v.y);
  out->set_z(v.z);
}

// A map as one raw matrix step: the exact doubles, so the converted spec
// walks the same maps bit for bit.
void AddMap(const PointMap& m, v1::Ifs& ifs) {
  v1::Map& out = *ifs.add_maps();
  v1::Matrix& mat = *out.add_steps()->mutable_matrix();
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 4; ++c) mat.add_values(m.pre.m[r][c]);
  for (const VariationTerm& v : m.variations) {
    v1::Variation& var = *out.add_variations();
    var.set_name(std::string(VariationName(v.kind)));
    var.set_weight(v.weight);
  }
  out.set_color(m.color);
}

}  // namespace

absl::StatusOr<v1::JobSpec> ExploreCandidateSpec(const std::string& template_bytes,
                                                 const ExploreCandidate& c,
                                                 const std::string& name) {
  v1::JobSpec spec;
  if (!spec.ParseFromString(template_bytes))
    return absl::InternalError("explore: the candidates' template does not parse");
  spec.set_name(name);
  v1::Grid& g = *spec.mutable_grid();
  SetVec3(c.params.frame.bounds.min, g.mutable_bounds_min());
  SetVec3(c.params.frame.bounds.max, g.mutable_bounds_max());
  v1::ChaosGame& cg = *spec.mutable_chaos_game();
  cg.set_seed(c.params.seed);
  v1::Ifs& ifs = *cg.mutable_ifs();
  bool expanding = false;
  for (const PointMap& m : c.params.ifs.maps) {
    AddMap(m, ifs);
    expanding |= m.pre.ContractionFactor() >= 1.0;
  }
  // The determinant test lets maps stretch in one direction: say so, or
  // the converter refuses them.
  if (expanding) ifs.set_allow_expanding(true);
  return spec;
}

}  // namespace nimbus::spec
