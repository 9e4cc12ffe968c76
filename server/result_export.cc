#include "server/result_export.h"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <optional>
#include <string>
#include <string_view>
#include <utility>

#include "absl/strings/str_cat.h"
#include "absl/time/time.h"
#include "core/base/file_digests.h"
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

// A store file shorter than the job's record says.
absl::Status ShortResultError(const JobRecord& rec, uint64_t at) {
  return absl::DataLossError(absl::StrCat("the result of job ", rec.id, " ends at ", at, " of ",
                                          rec.result_size, " bytes"));
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
    if (buffer.empty()) return ShortResultError(rec, offset);
    hash.Update(buffer);
    NIMBUS_RETURN_IF_ERROR(WriteAll(fd, buffer, part));
    offset += buffer.size();
  }
  return hash.HexDigest();
}

// A result this process wrote and hashed moments ago, unchanged since
// (same inode, size and modification time: RecallFileSha256), is copied by
// the kernel (copy_file_range) instead of read, hashed and written again.
// Returns the remembered digest, or nothing when the fast copy does not
// apply (another writer's file, a file system without it): the caller
// then copies and hashes. A failed write is an error either way.
absl::StatusOr<std::optional<std::string>> CopyKnown(ResultStore& results, const JobRecord& rec,
                                                     int fd, const std::filesystem::path& part) {
  const std::optional<std::filesystem::path> from = results.LocalFile(rec.result_key);
  if (!from) return std::nullopt;
  std::optional<std::string> sha = RecallFileSha256(*from);
  if (!sha) return std::nullopt;
  const int in = ::open(from->c_str(), O_RDONLY | O_CLOEXEC);
  if (in < 0) return std::nullopt;
  uint64_t done = 0;
  int err = 0;
  while (done < rec.result_size) {
    const ssize_t n = ::copy_file_range(in, nullptr, fd, nullptr, rec.result_size - done, 0);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      err = n < 0 ? errno : 0;
      break;
    }
    done += uint64_t(n);
  }
  ::close(in);
  if (done == rec.result_size) return sha;
  // Nothing copied: the file systems may lack the call.
  if (done == 0 && (err == EXDEV || err == ENOSYS || err == EOPNOTSUPP || err == EINVAL))
    return std::nullopt;
  if (err != 0) return DiskError(absl::StrCat("cannot write ", part.string()), err);
  return ShortResultError(rec, done);
}

// The result copied into `fd`, by the kernel where it may be; the digest
// of what was written.
absl::StatusOr<std::string> Copy(ResultStore& results, const JobRecord& rec, int fd,
                                 const std::filesystem::path& part) {
  NIMBUS_ASSIGN_OR_RETURN(std::optional<std::string> known, CopyKnown(results, rec, fd, part));
  if (known) return *std::move(known);
  return CopyHashed(results, rec, fd, part);
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

absl::Status ExportResult(JobQueue& store, ResultStore& results, const std::string& job_id,
                          const std::filesystem::path& path, int64_t retention_ms) {
  NIMBUS_ASSIGN_OR_RETURN(const JobRecord rec, store.Get(job_id));
  if (rec.result_expire_time != 0) return ResultExpiredError(rec, retention_ms);
  if (rec.state != JobState::kSucceeded) return ResultNotReadyError(rec);
  const std::filesystem::path part = path.string() + ".part";
  const int fd = ::open(part.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0666);
  if (fd < 0)
    return absl::PermissionDeniedError(
        absl::StrCat("cannot write ", part.string(), ": ", std::strerror(errno)));
  absl::StatusOr<std::string> sha = Copy(results, rec, fd, part);
  if (::close(fd) != 0 && sha.ok())
    sha = DiskError(absl::StrCat("cannot write ", part.string()), errno);
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
