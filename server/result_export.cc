#include "server/result_export.h"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <string>
#include <string_view>
#include <utility>

#include "absl/strings/str_cat.h"
#include "absl/time/time.h"
#include "core/base/sha256.h"
#include "core/base/status_macros.h"
#include "server/job_view.h"

namespace nimbus::server {

namespace {

// Big enough that per-call costs vanish, small enough to stay in L2
// between the read, the hash and the write (a quarter of this machine
// kind's 1 MiB), and few fresh pages to fault in: 64 of 4 KiB.
constexpr uint64_t kExportChunk = uint64_t{256} << 10;

absl::Status WriteAll(int fd, std::string_view data, const std::filesystem::path& path) {
  while (!data.empty()) {
    const ssize_t n = ::write(fd, data.data(), data.size());
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0)
      return DiskError(absl::StrCat("cannot write ", path.string()), n < 0 ? errno : ENOSPC);
    data.remove_prefix(size_t(n));
  }
  return absl::OkStatus();
}

// Streams the result into `fd`, hashing it; the hex digest of what was written.
absl::StatusOr<std::string> CopyHashed(ResultStore& results, const JobRecord& rec, int fd,
                                       const std::filesystem::path& part) {
  Sha256 hash;
  std::string buffer;
  uint64_t offset = 0;
  while (offset < rec.result_size) {
    NIMBUS_ASSIGN_OR_RETURN(buffer,
                            results.Read(rec.result_key, offset, kExportChunk, std::move(buffer)));
    if (buffer.empty())
      return absl::DataLossError(absl::StrCat("the result of job ", rec.id, " ends at ", offset,
                                              " of ", rec.result_size, " bytes"));
    hash.Update(buffer);
    NIMBUS_RETURN_IF_ERROR(WriteAll(fd, buffer, part));
    offset += buffer.size();
  }
  return hash.HexDigest();
}

}  // namespace

absl::Status ResultExpiredError(const JobRecord& rec, int64_t retention_ms) {
  return absl::FailedPreconditionError(absl::StrCat(
      "the result of job ", rec.id, " expired: it was deleted at ",
      absl::FormatTime("%Y-%m-%dT%H:%M:%SZ", absl::FromUnixMillis(rec.result_expire_time),
                       absl::UTCTimeZone()),
      retention_ms > 0 ? absl::StrCat(", as this server keeps results ", retention_ms / 1000,
                                      " s after their job ends")
                       : std::string(),
      "; pin jobs (nimbus pin) to keep their results"));
}

absl::Status ResultNotReadyError(const JobRecord& rec) {
  return absl::FailedPreconditionError(
      absl::StrCat("job ", rec.id, " is ", v1::JobState_Name(ToProto(rec.state)),
                   "; results exist only for JOB_STATE_SUCCEEDED"));
}

absl::Status ExportResult(JobStore& store, ResultStore& results, const std::string& job_id,
                          const std::filesystem::path& path, int64_t retention_ms) {
  NIMBUS_ASSIGN_OR_RETURN(const JobRecord rec, store.Get(job_id));
  if (rec.result_expire_time != 0) return ResultExpiredError(rec, retention_ms);
  if (rec.state != JobState::kSucceeded) return ResultNotReadyError(rec);
  const std::filesystem::path part = path.string() + ".part";
  const int fd = ::open(part.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0666);
  if (fd < 0)
    return absl::PermissionDeniedError(
        absl::StrCat("cannot write ", part.string(), ": ", std::strerror(errno)));
  absl::StatusOr<std::string> sha = CopyHashed(results, rec, fd, part);
  if (::close(fd) != 0 && sha.ok())
    sha = absl::ResourceExhaustedError(
        absl::StrCat("cannot write ", part.string(), ": ", std::strerror(errno)));
  std::error_code ec;
  if (sha.ok() && *sha != rec.result_sha256)
    sha = absl::DataLossError(absl::StrCat("sha256 mismatch for ", path.string(), ": got ", *sha,
                                           ", the job's record says ", rec.result_sha256));
  if (!sha.ok()) {
    std::filesystem::remove(part, ec);
    return sha.status();
  }
  std::filesystem::rename(part, path, ec);
  if (ec) return absl::InternalError(absl::StrCat("rename to ", path.string(), ": ", ec.message()));
  return absl::OkStatus();
}

}  // namespace nimbus::server
