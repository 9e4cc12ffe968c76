// Content-addressed storage of uploaded meshes and grids (docs/assets.md).
// A file is stored under its SHA-256 only after the bytes that arrived hash
// to the value the client announced and match its size, so a spec that
// names a hash always reads exactly the file its author had.
#pragma once

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "core/base/sha256.h"
#include "server/untrusted_file.h"

namespace nimbus::server {

struct AssetInfo {
  std::string sha256;
  uint64_t size = 0;
  std::filesystem::path path;
  /// The uploader had already uploaded these bytes before this upload
  /// (another principal's copy does not count).
  bool already_present = false;
  /// File names it was uploaded under, oldest first.
  std::vector<std::string> names;
  /// The format those names give (".obj", ...), or empty (spec::StoredAsset).
  std::string format;
};

/// @brief Assets by content as `dir`/<sha256>, with the names they were
/// uploaded under in `dir`/<sha256>.names (spec::FindStoredAssetInfo), so
/// the same bytes uploaded as "blob" and later as "cow.obj" become usable as
/// an OBJ. Data dirs of the older `dir`/<sha256><ext> layout are read as
/// they are.
class AssetStore {
 public:
  /// Largest accepted upload.
  static constexpr uint64_t kMaxAssetBytes = uint64_t{2} << 30;

  /// `sandbox` limits the child that reads an upload named as a mesh or grid.
  static absl::StatusOr<std::unique_ptr<AssetStore>> Open(const std::filesystem::path& dir,
                                                          SandboxLimits sandbox = {});

  const std::filesystem::path& dir() const { return dir_; }

  /// @brief One upload in progress. Bytes go to a private temporary file;
  /// destroying an unfinished upload deletes it.
  class Upload {
   public:
    ~Upload();
    /// Appends the next bytes. INVALID_ARGUMENT once more than the
    /// announced size arrived.
    absl::Status Append(const std::string& data);
    /// Checks size and hash and moves the file into place. INVALID_ARGUMENT
    /// for a truncated upload, DATA_LOSS for a hash mismatch. A file whose
    /// name gives a format (.vdb, .obj, .ply, .stl) is first read whole by a
    /// sandboxed child (server/untrusted_file.h); one that fails is refused
    /// with INVALID_ARGUMENT ("grid asset cow.vdb (sha256 3fa2c81d9e07...):
    /// not a readable VDB file: ...") and not stored.
    absl::StatusOr<AssetInfo> Finish();

   private:
    friend class AssetStore;
    Upload() = default;
    // The sandboxed read of a file whose name gives its format.
    absl::Status CheckContent() const;
    AssetStore* store_ = nullptr;
    std::string sha256_, name_, owner_;
    uint64_t expected_ = 0, received_ = 0;
    std::filesystem::path tmp_;
    std::ofstream out_;
    Sha256 hash_;
    bool done_ = false;
  };

  /// Starts an upload of `size` bytes announced to hash to `sha256`
  /// (lower-case hex). `file_name` (its last component) is remembered as a
  /// name of the asset, and `owner` (when not empty) as one of its owners.
  absl::StatusOr<std::unique_ptr<Upload>> Begin(const std::string& sha256, uint64_t size,
                                                const std::string& file_name,
                                                const std::string& owner = "");

  /// The stored file for a hash, or NOT_FOUND.
  absl::StatusOr<AssetInfo> Find(const std::string& sha256) const;

  /// Ownership: the same bytes uploaded by two principals belong to both.
  /// Owners sit in `dir`/<sha256>.owners, one per line. Recording an owner
  /// also restarts the asset's retention clock.
  absl::Status AddOwner(const std::string& sha256, const std::string& principal);
  bool IsOwner(const std::string& sha256, const std::string& principal) const;
  /// Bytes of the stored assets `principal` owns (for the asset quota).
  uint64_t OwnedBytes(const std::string& principal) const;
  /// Deletes the assets last uploaded before `cutoff` whose hash is not in
  /// `keep` (the assets of queued, running and pinned jobs), with their
  /// names and owners. Returns how many went.
  int ExpireUnreferenced(std::filesystem::file_time_type cutoff, const std::set<std::string>& keep);

 private:
  AssetStore(std::filesystem::path dir, SandboxLimits sandbox)
      : dir_(std::move(dir)), sandbox_(sandbox) {}
  /// Adds `line` to the sidecar file `path` unless it is there already or
  /// the file holds kMaxNames lines.
  absl::Status RememberLine(const std::filesystem::path& path, const std::string& sha256,
                            const std::string& line);
  std::filesystem::path OwnersPath(const std::string& sha256) const {
    return dir_ / (sha256 + ".owners");
  }

  /// Most names kept per asset; further ones are not recorded.
  static constexpr size_t kMaxNames = 64;

  std::filesystem::path dir_;
  SandboxLimits sandbox_;
  std::mutex names_mu_;  // serialises rewrites of the names files
};

/// The part of an uploaded file name that is kept as an asset name: the
/// last path component, without control characters, at most 255 bytes.
std::string CleanAssetName(const std::string& file_name);

}  // namespace nimbus::server
