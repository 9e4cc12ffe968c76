// Where finished volumes live. Behind an interface so an object store can
// replace the local folder when several replicas share the work.
//
// A result is one main file plus, for some generators (the set-IFS book),
// an ordered list of further files. Runners write the further files into
// ExtraFilesDir(scratch path) while they run; Commit moves them along.
#pragma once

#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "absl/status/statusor.h"

namespace nimbus::server {

/// One further file of a result.
struct StoredFile {
  std::string name;
  uint64_t size = 0;
  std::string sha256;
};

struct StoredResult {
  std::string key;
  uint64_t size = 0;
  std::string sha256;
  std::vector<StoredFile> files;
};

/// The folder for a result's further files, next to its scratch path. Only
/// finished files may appear under their final name (write elsewhere and
/// rename), because running jobs' files are listed and served.
std::filesystem::path ExtraFilesDir(const std::filesystem::path& scratch);

/// @brief Durable storage of result files by key.
class ResultStore {
 public:
  virtual ~ResultStore() = default;
  /// A scratch path where a worker may write a file before committing it.
  virtual std::filesystem::path ScratchPath(const std::string& key) = 0;
  /// Moves the scratch file (and its ExtraFilesDir) into the store, hashing
  /// every file.
  virtual absl::StatusOr<StoredResult> Commit(const std::string& key,
                                              const std::filesystem::path& scratch) = 0;
  /// Reads up to `max_bytes` at `offset`. Returns an empty string at EOF.
  virtual absl::StatusOr<std::string> Read(const std::string& key, uint64_t offset,
                                           uint64_t max_bytes) = 0;
  virtual absl::StatusOr<uint64_t> Size(const std::string& key) = 0;

  /// Further files of a committed result, in name order; or, when
  /// `running`, the finished files the job has written so far.
  virtual std::vector<StoredFile> ListFiles(const std::string& key, bool running) = 0;
  /// Reads part of a further file (committed, or written so far when
  /// `running`). NOT_FOUND for an unknown name.
  virtual absl::StatusOr<std::string> ReadFile(const std::string& key, const std::string& name,
                                               bool running, uint64_t offset,
                                               uint64_t max_bytes) = 0;
};

/// Results as files in `dir` (created if needed).
absl::StatusOr<std::unique_ptr<ResultStore>> OpenLocalResultStore(const std::filesystem::path& dir);

}  // namespace nimbus::server
