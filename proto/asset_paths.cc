// Where a spec's assets are: walking its Asset messages, making relative
// paths absolute, and finding an uploaded asset by hash. Small on purpose:
// the client includes it without the converters.
#include "proto/asset_paths.h"

#include <cctype>
#include <fstream>
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

std::filesystem::path StoredAssetNamesPath(const std::filesystem::path& dir,
                                           const std::string& sha256) {
  return dir / (sha256 + ".names");
}

std::string KnownAssetFormat(const std::string& name) {
  std::string ext = std::filesystem::path(name).extension().string();
  for (char& c : ext) c = char(std::tolower(static_cast<unsigned char>(c)));
  for (const char* known : {".obj", ".ply", ".stl", ".vdb"})
    if (ext == known) return ext;
  return {};
}

absl::StatusOr<StoredAsset> FindStoredAssetInfo(const std::filesystem::path& dir,
                                                const std::string& sha256) {
  StoredAsset out;
  std::error_code ec;
  // The content-only name first; then the layout that baked the first
  // upload's extension into the name, whose extension counts as a name.
  std::string old_name;  // "<sha256><ext>" of the older layout
  if (std::filesystem::is_regular_file(dir / sha256, ec)) {
    out.path = dir / sha256;
  } else {
    for (const char* ext : {".obj", ".ply", ".stl", ".vdb", ".bin"}) {
      const std::filesystem::path p = dir / (sha256 + ext);
      if (!std::filesystem::is_regular_file(p, ec)) continue;
      out.path = p;
      old_name = p.filename().string();
      break;
    }
  }
  if (out.path.empty()) return absl::NotFoundError(StrCat("no stored asset ", sha256));
  std::ifstream names(StoredAssetNamesPath(dir, sha256));
  for (std::string line; std::getline(names, line);)
    if (!line.empty()) out.names.push_back(line);
  out.format = KnownAssetFormat(old_name);
  for (size_t i = 0; i < out.names.size() && out.format.empty(); ++i)
    out.format = KnownAssetFormat(out.names[i]);
  return out;
}

absl::StatusOr<std::filesystem::path> FindStoredAsset(const std::filesystem::path& dir,
                                                      const std::string& sha256) {
  auto info = FindStoredAssetInfo(dir, sha256);
  if (!info.ok()) return info.status();
  return info->path;
}

std::string AssetFormat(const std::string& label, const StoredAsset& stored) {
  std::string from_label = KnownAssetFormat(label);
  return from_label.empty() ? stored.format : from_label;
}

std::string AssetDisplayName(const std::string& label, const std::string& sha256) {
  if (label.empty()) return StrCat("sha256 ", sha256);
  return StrCat(label, " (sha256 ", sha256.substr(0, 12), "...)");
}

void ForEachAsset(v1::JobSpec& spec,
                  const std::function<void(const std::string& field, v1::Asset& asset)>& f) {
  if (spec.has_fractal_field() && spec.fractal_field().shape().has_source())
    VisitSource(*spec.mutable_fractal_field()->mutable_shape()->mutable_source(),
                "fractal_field.shape.source", f);
  if (!spec.has_set_ifs()) return;
  v1::SetIfs* s = spec.mutable_set_ifs();
  for (int i = 0; i < s->maps_size(); ++i)
    if (s->maps(i).has_condensation())
      VisitSource(*s->mutable_maps(i)->mutable_condensation(),
                  StrCat("set_ifs.maps[", i, "].condensation"), f);
  if (s->has_start()) VisitSource(*s->mutable_start(), "set_ifs.start", f);
}

absl::Status LocalPathRefused(const std::string& field) {
  return absl::InvalidArgumentError(
      StrCat(field,
             ".path: this server never opens files named in a spec; upload the file and "
             "give its sha256 instead (the nimbus CLI does this)"));
}

absl::Status RefuseAssetPaths(const v1::JobSpec& spec) {
  v1::JobSpec copy = spec;  // ForEachAsset visits mutable assets
  absl::Status result;
  ForEachAsset(copy, [&](const std::string& field, v1::Asset& a) {
    if (result.ok() && a.source_case() == v1::Asset::kPath) result = LocalPathRefused(field);
  });
  return result;
}

void ResolveAssetPaths(v1::JobSpec& spec, const std::filesystem::path& base_dir) {
  ForEachAsset(spec, [&](const std::string&, v1::Asset& a) {
    if (a.source_case() != v1::Asset::kPath || a.path().empty()) return;
    const std::filesystem::path p(a.path());
    if (p.is_relative()) a.set_path((base_dir / p).lexically_normal().string());
  });
}

}  // namespace nimbus::spec
