// Where a spec's assets are: walking its Asset messages, making relative
// paths absolute, and finding an uploaded asset by hash. Small on purpose:
// the client includes it without the converters.
#include "proto/asset_paths.h"

#include <system_error>

#include "absl/strings/str_cat.h"

namespace nimbus::spec {

using absl::StrCat;

namespace {

// Walks every SetSource of a message tree.
void VisitSource(v1::SetSource& s, const std::string& field,
                 const std::function<void(const std::string&, v1::Asset&)>& f) {
  switch (s.kind_case()) {
    case v1::SetSource::kMesh:
      f(field + ".mesh.asset", *s.mutable_mesh()->mutable_asset());
      break;
    case v1::SetSource::kGrid:
      f(field + ".grid.asset", *s.mutable_grid()->mutable_asset());
      break;
    case v1::SetSource::kRandomBalls:
      if (s.random_balls().has_inside())
        VisitSource(*s.mutable_random_balls()->mutable_inside(), field + ".random_balls.inside", f);
      break;
    case v1::SetSource::kUnion:
      for (int i = 0; i < s.union_().parts_size(); ++i)
        VisitSource(*s.mutable_union_()->mutable_parts(i), StrCat(field, ".union.parts[", i, "]"),
                    f);
      break;
    default:
      break;
  }
}

}  // namespace

absl::StatusOr<std::filesystem::path> FindStoredAsset(const std::filesystem::path& dir,
                                                      const std::string& sha256) {
  std::error_code ec;
  // The extension is kept so the format can still be told from the name.
  for (const char* ext : {".obj", ".ply", ".stl", ".vdb", ".bin"}) {
    std::filesystem::path p = dir / (sha256 + ext);
    if (std::filesystem::is_regular_file(p, ec)) return p;
  }
  return absl::NotFoundError(StrCat("no stored asset ", sha256));
}

void ForEachAsset(v1::JobSpec& spec,
                  const std::function<void(const std::string& field, v1::Asset& asset)>& f) {
  if (!spec.has_set_ifs()) return;
  v1::SetIfs* s = spec.mutable_set_ifs();
  for (int i = 0; i < s->maps_size(); ++i)
    if (s->maps(i).has_condensation())
      VisitSource(*s->mutable_maps(i)->mutable_condensation(),
                  StrCat("set_ifs.maps[", i, "].condensation"), f);
  if (s->has_start()) VisitSource(*s->mutable_start(), "set_ifs.start", f);
}

void ResolveAssetPaths(v1::JobSpec& spec, const std::filesystem::path& base_dir) {
  ForEachAsset(spec, [&](const std::string&, v1::Asset& a) {
    if (a.source_case() != v1::Asset::kPath || a.path().empty()) return;
    const std::filesystem::path p(a.path());
    if (p.is_relative()) a.set_path((base_dir / p).lexically_normal().string());
  });
}

}  // namespace nimbus::spec
