// DataDirLock: one Nimbus server per SQLite data folder.
//
//   NIMBUS_ASSIGN_OR_RETURN(DataDirLock lock, DataDirLock::Acquire(dir));
//   // held until `lock` is destroyed or the process exits
#pragma once

#include <filesystem>

#include "absl/status/statusor.h"

namespace nimbus::server {

/// @brief An exclusive flock on `<data_dir>/server.lock`, which also records
/// the holder's pid. A SQLite queue has no way to tell another process's
/// watchers that a job ended, so a second server on the same folder would
/// run their jobs while they wait forever; it is refused instead. The kernel
/// drops the lock when the holder exits, however it exits.
class DataDirLock {
 public:
  /// FAILED_PRECONDITION naming the folder and the holder's pid when
  /// another process holds it.
  static absl::StatusOr<DataDirLock> Acquire(const std::filesystem::path& data_dir);

  DataDirLock(DataDirLock&& other) noexcept : fd_(other.fd_) { other.fd_ = -1; }
  DataDirLock& operator=(DataDirLock&& other) noexcept;
  ~DataDirLock();

 private:
  explicit DataDirLock(int fd) : fd_(fd) {}
  int fd_ = -1;
};

}  // namespace nimbus::server
