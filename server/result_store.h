// Where finished volumes live. Behind an interface so an object store can
// replace the local folder when several replicas share the work.
#pragma once

#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>

#include "absl/status/statusor.h"

namespace nimbus::server {

struct StoredResult {
  std::string key;
  uint64_t size = 0;
  std::string sha256;
};

/// @brief Durable storage of result files by key.
class ResultStore {
 public:
  virtual ~ResultStore() = default;
  /// A scratch path where a worker may write a file before committing it.
  virtual std::filesystem::path ScratchPath(const std::string& key) = 0;
  /// Moves the scratch file into the store, hashing it.
  virtual absl::StatusOr<StoredResult> Commit(const std::string& key,
                                              const std::filesystem::path& scratch) = 0;
  /// Reads up to `max_bytes` at `offset`. Returns an empty string at EOF.
  virtual absl::StatusOr<std::string> Read(const std::string& key, uint64_t offset,
                                           uint64_t max_bytes) = 0;
  virtual absl::StatusOr<uint64_t> Size(const std::string& key) = 0;
};

/// Results as files in `dir` (created if needed).
absl::StatusOr<std::unique_ptr<ResultStore>> OpenLocalResultStore(const std::filesystem::path& dir);

}  // namespace nimbus::server
