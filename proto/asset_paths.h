// Where a spec's assets are: every Asset message of a spec (mesh and grid
// sources at any depth), relative paths made absolute, and an uploaded
// asset found by its hash. The client uses this without the converters.
#pragma once

#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "nimbus/v1/spec.pb.h"

namespace nimbus::spec {

/// A stored asset: its bytes and what it is known as. Assets are stored by
/// content only, as `dir`/<sha256>; the names of the files it was uploaded
/// from sit next to it in `dir`/<sha256>.names, one per line, oldest first.
/// Data dirs from before keep working: `dir`/<sha256><ext> (.obj, .ply,
/// .stl, .vdb, .bin) is found too, its extension counting as a name.
struct StoredAsset {
  std::filesystem::path path;
  /// Upload file names (no folders), oldest first.
  std::vector<std::string> names;
  /// The format those names give (".obj", ".ply", ".stl", ".vdb"), from
  /// the oldest name that has one, so a later upload under another name
  /// never changes how a usable asset reads; empty when none gives one.
  std::string format;
};

/// The stored asset for a hash. NOT_FOUND names the hash (never a server
/// path) when no upload has it.
absl::StatusOr<StoredAsset> FindStoredAssetInfo(const std::filesystem::path& dir,
                                                const std::string& sha256);

/// The checked copy of a stored grid asset: its float grids as the
/// sandboxed checker re-wrote them (server/untrusted_file.h). nimbusd reads
/// grid assets only from there.
inline std::filesystem::path LaunderedPath(const std::filesystem::path& stored) {
  return std::filesystem::path(stored.string() + ".laundered");
}

/// Where a stored asset's bytes are (FindStoredAssetInfo(...).path).
absl::StatusOr<std::filesystem::path> FindStoredAsset(const std::filesystem::path& dir,
                                                      const std::string& sha256);

/// The sidecar listing an asset's upload names: `dir`/<sha256>.names.
std::filesystem::path StoredAssetNamesPath(const std::filesystem::path& dir,
                                           const std::string& sha256);

/// The lower-cased extension of `name` when it is a format assets come in
/// (".obj", ".ply", ".stl", ".vdb"), else empty.
std::string KnownAssetFormat(const std::string& name);

/// The format to read an asset as: its label's extension when that is a
/// known format (the spec's word wins), else the one its uploads gave.
std::string AssetFormat(const std::string& label, const StoredAsset& stored);

/// How messages name an uploaded asset: "cow.obj (sha256 3fa2c81d9e07...)",
/// or the bare hash without a label. Never a server path.
std::string AssetDisplayName(const std::string& label, const std::string& sha256);

/// Calls `f(path_field, asset)` for every Asset message of the spec (mesh
/// and grid sources, at any depth), so clients can upload and rewrite them.
void ForEachAsset(v1::JobSpec& spec,
                  const std::function<void(const std::string& field, v1::Asset& asset)>& f);

/// The one answer a server reached over the network gives to an asset named
/// by `path`: INVALID_ARGUMENT naming `field`, the same words whatever exists
/// at that path (or does not), since the server never looks.
absl::Status LocalPathRefused(const std::string& field);

/// Refuses a spec that names any asset by `path`, with LocalPathRefused for
/// the first one; makes no file system call. A server that listens on a
/// network calls it before reading any asset (CheckSpecAssets).
absl::Status RefuseAssetPaths(const v1::JobSpec& spec);

/// Makes relative asset paths absolute against `base_dir` (the spec file's
/// folder), as the CLI does before uploading.
void ResolveAssetPaths(v1::JobSpec& spec, const std::filesystem::path& base_dir);

}  // namespace nimbus::spec
