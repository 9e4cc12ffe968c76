// Small valid specs of every generator, each paired with a copy that
// differs in one top-level JobSpec field (or inside one generator): the
// cases of the result-cache key tests (docs/result_cache.md). Header only:
// it needs the spec library, which the server, client and e2e tests link.
#pragma once

#include <string>
#include <vector>

#include "proto/spec_io.h"

namespace nimbus::testing {

/// `base` and `changed` differ only in JobSpec field `field` (a top-level
/// field name). Both convert; chaos games, set IFS, fields and
/// explorations run in about a second on two threads.
struct SpecChange {
  std::string field;
  v1::JobSpec base, changed;
};

inline v1::JobSpec SpecFromJson(const std::string& json) {
  auto spec = spec::ParseSpec(json, spec::SpecFormat::kJson);
  return spec.ok() ? *spec : v1::JobSpec();
}

/// The Sierpinski triangle, 16^3 voxels, 2^20 points.
inline v1::JobSpec SmallChaosGame() {
  return SpecFromJson(R"({"name": "cache", "grid": {"resolution": [16]},
    "chaos_game": {"ifs": {"maps": [
      {"steps": [{"scale": {"uniform": 0.5}}]},
      {"steps": [{"translate": {"x": 0.5}}, {"scale": {"uniform": 0.5}}]},
      {"steps": [{"translate": {"y": 0.5}}, {"scale": {"uniform": 0.5}}]}]},
      "iterations": "1048576", "seed": "1"}})");
}

inline v1::JobSpec SmallSetIfs() {
  return SpecFromJson(R"({"name": "cache_sets", "grid": {"resolution": [16]},
    "set_ifs": {"maps": [
      {"probability": 2, "condensation": {"sphere": {"radius": 0.4}}},
      {"probability": 1, "condensation": {"sphere": {"center": {"x": 0.5}, "radius": 0.2}}}],
      "random": {"iterations": "50"}}})");
}

inline v1::JobSpec SmallFractalField() {
  return SpecFromJson(R"({"name": "cache_field", "grid": {"resolution": [16]},
    "fractal_field": {"field": {"dimensions": 3, "seed": "1",
      "mesh_series": {"base_cell_size": [0.5], "count": 2}}}})");
}

inline v1::JobSpec SmallExplore() {
  return SpecFromJson(R"({"name": "cache_explore", "explore": {"count": 1, "seed": "12",
    "dimensions": 2, "min_maps": 3, "max_maps": 3, "thumbnail_size": 32,
    "thumbnail_iterations": "65536"}})");
}

inline v1::JobSpec SmallJelly() {
  return SpecFromJson(R"({"name": "cache_jelly", "grid": {"resolution": [16]},
    "jelly": {"bodies": [{"scale": {"uniform": 0.5}, "position": {"y": 0.5}}],
      "frames": 2, "depth": 1}})");
}

/// One change per top-level field of a cacheable spec, and one inside each
/// generator (jelly included: jelly jobs skip the cache, but their hash
/// still names the result).
inline std::vector<SpecChange> TopLevelSpecChanges() {
  std::vector<SpecChange> out;
  auto add = [&](const std::string& field, const v1::JobSpec& base, auto&& edit) {
    SpecChange c{field, base, base};
    edit(c.changed);
    out.push_back(std::move(c));
  };
  const v1::JobSpec game = SmallChaosGame();
  add("name", game, [](v1::JobSpec& s) { s.set_name("cache2"); });
  add("grid", game, [](v1::JobSpec& s) { s.mutable_grid()->set_resolution(0, 18); });
  add("output", game, [](v1::JobSpec& s) {
    s.mutable_output()->set_density_mapping(v1::DENSITY_MAPPING_LOG);
  });
  add("image", game, [](v1::JobSpec& s) {
    s.mutable_image()->set_width(32);
    s.mutable_image()->set_height(32);
  });
  add("detail", game, [](v1::JobSpec& s) {
    v1::FieldSource& f = *s.mutable_detail()->mutable_field();
    f.set_dimensions(3);
    f.set_seed(4);
    f.mutable_mesh_series()->add_base_cell_size(0.5);
    f.mutable_mesh_series()->set_count(2);
  });
  add("chaos_game", game, [](v1::JobSpec& s) { s.mutable_chaos_game()->set_seed(2); });
  add("set_ifs", SmallSetIfs(),
      [](v1::JobSpec& s) { s.mutable_set_ifs()->mutable_random()->set_iterations(60); });
  add("fractal_field", SmallFractalField(),
      [](v1::JobSpec& s) { s.mutable_fractal_field()->mutable_field()->set_seed(2); });
  add("explore", SmallExplore(), [](v1::JobSpec& s) { s.mutable_explore()->set_seed(13); });
  add("jelly", SmallJelly(), [](v1::JobSpec& s) { s.mutable_jelly()->set_frames(3); });
  return out;
}

}  // namespace nimbus::testing
