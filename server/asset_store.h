// Content-addressed storage of uploaded meshes and grids (docs/assets.md).
// A file is stored under its SHA-256 only after the bytes that arrived hash
// to the value the client announced and match its size, so a spec that
// names a hash always reads exactly the file its author had.
#pragma once

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>

#include "absl/status/statusor.h"
#include "core/base/sha256.h"

namespace nimbus::server {

struct AssetInfo {
  std::string sha256;
  uint64_t size = 0;
  std::filesystem::path path;
  /// The store had the file before this upload.
  bool already_present = false;
};

/// @brief Assets as `dir`/<sha256><ext>, the extension (.obj, .ply, .stl,
/// .vdb) taken from the uploaded file's name so formats stay recognisable.
class AssetStore {
 public:
  /// Largest accepted upload.
  static constexpr uint64_t kMaxAssetBytes = uint64_t{2} << 30;

  static absl::StatusOr<std::unique_ptr<AssetStore>> Open(const std::filesystem::path& dir);

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
    /// for a truncated upload, DATA_LOSS for a hash mismatch.
    absl::StatusOr<AssetInfo> Finish();

   private:
    friend class AssetStore;
    Upload() = default;
    AssetStore* store_ = nullptr;
    std::string sha256_, ext_;
    uint64_t expected_ = 0, received_ = 0;
    std::filesystem::path tmp_;
    std::ofstream out_;
    Sha256 hash_;
    bool done_ = false;
  };

  /// Starts an upload of `size` bytes announced to hash to `sha256`
  /// (lower-case hex). `file_name` gives the extension.
  absl::StatusOr<std::unique_ptr<Upload>> Begin(const std::string& sha256, uint64_t size,
                                                const std::string& file_name);

  /// The stored file for a hash, or NOT_FOUND.
  absl::StatusOr<AssetInfo> Find(const std::string& sha256) const;

 private:
  explicit AssetStore(std::filesystem::path dir) : dir_(std::move(dir)) {}
  std::filesystem::path dir_;
};

/// The extension an asset is stored with: the file name's (lower-cased) if
/// it is a known mesh or grid format, ".bin" otherwise.
std::string AssetExtension(const std::string& file_name);

}  // namespace nimbus::server
