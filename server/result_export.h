// @brief A succeeded job's main result copied out of the store to a local
// file by the process that runs the server: what FetchResult gives a
// client, without the gRPC stream (the CLI's embedded server).
//
//   if (auto s = ExportResult(*store, *results, job_id, "out/cloud.vdb"); !s.ok()) ...
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>

#include "absl/status/status.h"
#include "server/job_store.h"
#include "server/result_store.h"

namespace nimbus::server {

/// FAILED_PRECONDITION for a result the retention sweep deleted: when, and
/// why (`retention_ms` > 0 names the server's keep time).
absl::Status ResultExpiredError(const JobRecord& rec, int64_t retention_ms);

/// FAILED_PRECONDITION for a job whose result is not there yet (or never
/// will be): its state, and that results exist only for SUCCEEDED jobs.
absl::Status ResultNotReadyError(const JobRecord& rec);

/// Copies job `job_id`'s committed result to `path`, hashing the bytes as
/// they pass. The copy is written beside `path` and renamed over it only
/// when its size and SHA-256 match the job's record; otherwise DATA_LOSS
/// and `path` is untouched. A result this process wrote moments ago and
/// that is unchanged since (RecallFileSha256: same inode, size and
/// modification time as when its writer hashed it) is copied by the kernel
/// instead, checked against the record by that digest and by its size.
/// NOT_FOUND for an unknown job, FAILED_PRECONDITION for one that has not
/// succeeded or whose result expired. Blocking I/O: never call it on a
/// gRPC thread.
absl::Status ExportResult(JobQueue& store, ResultStore& results, const std::string& job_id,
                          const std::filesystem::path& path, int64_t retention_ms = 0);

}  // namespace nimbus::server
