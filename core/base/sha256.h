// SHA-256 digests (OpenSSL behind the header), for result files, uploads
// and spec hashes.
#pragma once

#include <filesystem>
#include <memory>
#include <string>
#include <string_view>

#include "absl/status/statusor.h"

namespace nimbus {

/// @brief Incremental SHA-256.
class Sha256 {
 public:
  Sha256();
  ~Sha256();
  Sha256(const Sha256&) = delete;
  Sha256& operator=(const Sha256&) = delete;
  void Update(std::string_view data);
  /// Lower-case hex digest; the object must not be updated afterwards.
  std::string HexDigest();

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

std::string Sha256Hex(std::string_view data);
absl::StatusOr<std::string> Sha256File(const std::filesystem::path& path);
/// Feeds a whole file to `h` (a download resuming from a partial file).
absl::Status HashFileInto(const std::filesystem::path& path, Sha256& h);

}  // namespace nimbus
