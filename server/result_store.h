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
#include <optional>
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
  /// every file. All or nothing: on failure nothing of the result is left
  /// under its final name (a full disk is RESOURCE_EXHAUSTED).
  virtual absl::StatusOr<StoredResult> Commit(const std::string& key,
                                              const std::filesystem::path& scratch) = 0;
  /// Reads up to `max_bytes` at `offset`. Returns an empty string at EOF.
  /// The answer reuses `buffer`'s storage: a streaming reader that hands
  /// each chunk back saves an allocation and a zero fill per chunk.
  virtual absl::StatusOr<std::string> Read(const std::string& key, uint64_t offset,
                                           uint64_t max_bytes, std::string buffer = {}) = 0;
  virtual absl::StatusOr<uint64_t> Size(const std::string& key) = 0;
  /// The committed result's own file where the store keeps it on this
  /// machine's file system (an exporter may then copy it in the kernel);
  /// nothing for stores elsewhere.
  virtual std::optional<std::filesystem::path> LocalFile(const std::string& key) {
    (void)key;
    return std::nullopt;
  }
  /// Removes a committed result and its further files (retention, or a
  /// deleted job); returns the bytes freed. A missing result frees 0.
  virtual absl::StatusOr<uint64_t> Delete(const std::string& key) = 0;

  /// A copy of the committed result `from_key` (further files of job
  /// `from_id` included) committed under `to_key`, for the result cache
  /// (docs/result_cache.md): each job's files then live and expire on their
  /// own. This default reads and commits through the other methods.
  virtual absl::StatusOr<StoredResult> CopyResult(const std::string& from_key,
                                                  const std::string& from_id,
                                                  const std::string& to_key);

  /// Further files of a committed result, in name order; or, when
  /// `running`, the finished files the job has written so far.
  virtual std::vector<StoredFile> ListFiles(const std::string& key, bool running) = 0;
  /// RESOURCE_EXHAUSTED when less than the store's free-space reserve is
  /// left, so new jobs are refused before the disk fills (SubmitJob calls
  /// it). Cheap: one statvfs.
  virtual absl::Status CheckFreeSpace() { return absl::OkStatus(); }
  /// Reads part of a further file (committed, or written so far when
  /// `running`). NOT_FOUND for an unknown name. `buffer` as for Read.
  virtual absl::StatusOr<std::string> ReadFile(const std::string& key, const std::string& name,
                                               bool running, uint64_t offset, uint64_t max_bytes,
                                               std::string buffer = {}) = 0;
};

/// A failed write of a result: RESOURCE_EXHAUSTED "disk full while writing
/// the result: WHAT: reason" for a full disk or quota (ENOSPC, EDQUOT),
/// INTERNAL "WHAT: reason" otherwise.
absl::Status DiskError(const std::string& what, int err);

/// Results as files in `dir` (created if needed). CheckFreeSpace refuses
/// work while the file system holding `dir` has less than
/// `min_free_bytes` available (0: never).
absl::StatusOr<std::unique_ptr<ResultStore>> OpenLocalResultStore(const std::filesystem::path& dir,
                                                                  uint64_t min_free_bytes = 0);

/// Results in a folder several replicas share (a volume or NFS mount):
/// each writer (`writer`: its replica id) has scratch files of its own, a
/// result appears by atomic rename with its sha256 beside it, and a read
/// from the start of a result checks the content against that hash
/// (DATA_LOSS on a mismatch). Running jobs' files are found whichever
/// replica writes them.
absl::StatusOr<std::unique_ptr<ResultStore>> OpenSharedResultStore(
    const std::filesystem::path& dir, const std::string& writer, uint64_t min_free_bytes = 0);

}  // namespace nimbus::server
