#include "core/io/vdb_file.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cstring>
#include <fstream>
#include <new>
#include <string_view>
#include <system_error>
#include <thread>
#include <vector>

#include "absl/strings/str_cat.h"
#include "core/base/file_digests.h"
#include "core/base/sha256.h"
#include "core/io/leaf_runs.h"

namespace nimbus::vdb_internal {

namespace {
// OpenVDB's header: magic (8 bytes), file version, library major and minor
// (4 each), the grid-offsets flag (1), then the UUID as 36 characters.
constexpr size_t kUuidOffset = 21;
constexpr size_t kUuidSize = 36;

bool LooksLikeHeader(std::string_view head) {
  if (head.size() < kUuidOffset + kUuidSize) return false;
  int64_t magic = 0;
  std::memcpy(&magic, head.data(), sizeof(magic));
  return magic == kVdbMagic && head[kUuidOffset + 8] == '-' &&
         head[kUuidOffset + 13] == '-';
}

// A version-8 (custom) UUID from a digest's first 32 hex digits.
std::string UuidFromDigest(const std::string& hex) {
  std::string u = hex.substr(0, 32);
  u[12] = '8';
  u[16] = "89ab"[std::stoi(u.substr(16, 1), nullptr, 16) & 3];
  return u.substr(0, 8) + "-" + u.substr(8, 4) + "-" + u.substr(12, 4) + "-" + u.substr(16, 4) +
         "-" + u.substr(20, 12);
}
}  // namespace

void StampContentUuid(std::string& bytes) {
  if (!LooksLikeHeader(bytes)) return;
  Sha256 h;
  h.Update(std::string_view(bytes).substr(0, kUuidOffset));
  h.Update(std::string_view(bytes).substr(kUuidOffset + kUuidSize));
  const std::string uuid = UuidFromDigest(h.HexDigest());
  bytes.replace(kUuidOffset, kUuidSize, uuid);
}

namespace {

std::atomic<int64_t> g_fail_after{-1};
std::atomic<int> g_fail_errno{0};

// The status of a failed write: a full disk or quota is the client's
// RESOURCE_EXHAUSTED (retry later, or somewhere else), anything else an
// internal error; both name the file.
absl::Status WriteError(const std::filesystem::path& path, int err, const std::string& what) {
  const std::string detail = absl::StrCat(path.string(), ": ", what, ": ", std::strerror(err));
  if (err == ENOSPC || err == EDQUOT)
    return absl::ResourceExhaustedError(
        absl::StrCat("disk full while writing the result: ", detail));
  return absl::InternalError(absl::StrCat("cannot write the result: ", detail));
}

// A seekable output buffer over a file descriptor that keeps the first
// write error: std::ofstream (and so openvdb::io::File) loses errno and
// OpenVDB never checks the stream, so a full disk left a short file that
// looked written. While the file is written front to back (the native
// writer) it also hashes the content for the UUID as the bytes pass, so
// the file need not be read again to stamp it.
class CheckedFileBuf : public std::streambuf {
 public:
  explicit CheckedFileBuf(int fd) : fd_(fd), buf_(size_t{1} << 16) {
    setp(buf_.data(), buf_.data() + buf_.size());
  }
  int error() const { return error_; }
  uint64_t end() const { return end_; }
  bool Flush() {
    const char* p = pbase();
    size_t n = size_t(pptr() - pbase());
    setp(buf_.data(), buf_.data() + buf_.size());
    Hash(p, n);
    while (n > 0 && error_ == 0) {
      const int64_t limit = g_fail_after.load();
      if (limit >= 0 && pos_ + n > uint64_t(limit)) {
        error_ = g_fail_errno.load();
        break;
      }
      const ssize_t w = ::pwrite(fd_, p, n, off_t(pos_));
      if (w < 0 && errno == EINTR) continue;
      if (w <= 0) {
        error_ = w < 0 ? errno : ENOSPC;
        break;
      }
      p += w, n -= size_t(w), pos_ += uint64_t(w);
      end_ = std::max(end_, pos_);
    }
    StartWriteback();
    return error_ == 0;
  }
  /// The content UUID of a file written front to back with a VDB header;
  /// empty when it was not (then the file must be read to stamp it).
  std::string ContentUuid() {
    if (!sequential_ || hashed_ != end_ || !LooksLikeHeader(head_)) return "";
    return UuidFromDigest(content_.HexDigest());
  }

 protected:
  int_type overflow(int_type ch) override {
    if (!Flush()) return traits_type::eof();
    if (!traits_type::eq_int_type(ch, traits_type::eof())) {
      *pptr() = char(ch);
      pbump(1);
    }
    return traits_type::not_eof(ch);
  }
  int sync() override { return Flush() ? 0 : -1; }
  pos_type seekoff(off_type off, std::ios_base::seekdir dir, std::ios_base::openmode) override {
    if (!Flush()) return pos_type(off_type(-1));
    const int64_t base = dir == std::ios_base::beg   ? 0
                         : dir == std::ios_base::cur ? int64_t(pos_)
                                                     : int64_t(end_);
    if (base + off < 0) return pos_type(off_type(-1));
    pos_ = uint64_t(base + off);
    return pos_type(off_type(pos_));
  }
  pos_type seekpos(pos_type p, std::ios_base::openmode m) override {
    return seekoff(off_type(p), std::ios_base::beg, m);
  }

 private:
  // Feeds bytes about to be written at pos_ to the content hash, all but
  // the UUID's; any write not at the hashed end (a back-patch) ends it.
  void Hash(const char* p, size_t n) {
    if (!sequential_ || n == 0) return;
    if (pos_ != hashed_) {
      sequential_ = false;
      return;
    }
    const uint64_t a = pos_, b = pos_ + n;
    if (a < kUuidOffset + kUuidSize)
      head_.append(p, size_t(std::min<uint64_t>(b, kUuidOffset + kUuidSize) - a));
    if (a < kUuidOffset) content_.Update({p, size_t(std::min<uint64_t>(b, kUuidOffset) - a)});
    const uint64_t from = std::max<uint64_t>(a, kUuidOffset + kUuidSize);
    if (from < b) content_.Update({p + (from - a), size_t(b - from)});
    hashed_ = b;
  }

  // Asks the kernel to start writing each few MiB out while the rest is
  // still being encoded, so the final fsync waits for the last of them
  // only. Advice: a failure here shows in the fsync.
  void StartWriteback() {
    constexpr uint64_t kStep = uint64_t{4} << 20;
    if (!sequential_ || pos_ < started_ + kStep) return;
    ::sync_file_range(fd_, off_t(started_), off_t(pos_ - started_), SYNC_FILE_RANGE_WRITE);
    started_ = pos_;
  }

  int fd_;
  uint64_t started_ = 0;  // writeback was started below this offset
  std::vector<char> buf_;
  int error_ = 0;
  uint64_t pos_ = 0, end_ = 0;
  Sha256 content_;
  std::string head_;  // the first bytes, up to the UUID's end
  uint64_t hashed_ = 0;
  bool sequential_ = true;
};

absl::Status SyncFile(int fd, const std::filesystem::path& path) {
  if (::fsync(fd) != 0) return WriteError(path, errno, "fsync failed");
  return absl::OkStatus();
}

// fsyncs the finished file while this thread hashes it: the disk wait costs
// no CPU, and the result store's commit then recalls the digest instead of
// reading the file again (RecallFileSha256).
absl::Status SyncWhileHashing(int fd, const std::filesystem::path& tmp,
                              const std::filesystem::path& path) {
  int sync_errno = 0;
  std::thread sync;
  try {
    sync = std::thread([&] {
      if (::fsync(fd) != 0) sync_errno = errno;
    });
  } catch (const std::system_error&) {
    return SyncFile(fd, path);  // no thread to spare: sync and let the commit hash
  }
  absl::StatusOr<std::string> sha = absl::UnavailableError("not hashed");
  try {
    sha = Sha256File(tmp);
  } catch (const std::bad_alloc&) {
    // The commit hashes it instead.
  }
  sync.join();
  if (sync_errno != 0) return WriteError(path, sync_errno, "fsync failed");
  if (sha.ok()) RememberFileSha256(fd, *sha);
  return absl::OkStatus();
}

// Writes the archive to `tmp`, stamps its UUID when it could hash the
// content on the way (`stamped`), fsyncs it and checks its size on disk.
absl::Status WriteChecked(const std::filesystem::path& path, const std::filesystem::path& tmp,
                          const ArchiveFn& write_archive, bool& stamped) {
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) return WriteError(path, errno, "cannot create " + tmp.filename().string());
  CheckedFileBuf buf(fd);
  std::ostream os(&buf);
  absl::Status st;
  try {
    write_archive(os);
    os.flush();
  } catch (const SpillFileError& e) {
    // The leaves waiting on the result's disk: the same disk, the same
    // error. A spill folder of the caller's own choosing is named too.
    const bool elsewhere = !e.dir().empty() && e.dir() != path.parent_path();
    st = WriteError(path, e.error(),
                    absl::StrCat(e.what(), elsewhere ? " in " + e.dir().string() : ""));
  } catch (const std::exception& e) {
    if (buf.error() == 0)
      st = absl::InternalError(absl::StrCat("writing ", path.string(), ": ", e.what()));
  }
  buf.Flush();
  if (st.ok() && buf.error() != 0) st = WriteError(path, buf.error(), "write failed");
  const std::string uuid = st.ok() ? buf.ContentUuid() : "";
  if (!uuid.empty()) {
    stamped = ::pwrite(fd, uuid.data(), uuid.size(), off_t(kUuidOffset)) == ssize_t(uuid.size());
    if (!stamped) st = WriteError(path, errno, "cannot stamp the UUID");
  }
  if (st.ok()) st = stamped ? SyncWhileHashing(fd, tmp, path) : SyncFile(fd, path);
  struct stat sb {};
  if (st.ok() && (::fstat(fd, &sb) != 0 || uint64_t(sb.st_size) != buf.end()))
    st = absl::InternalError(absl::StrCat("writing ", path.string(), ": ", buf.end(),
                                          " bytes written but the file holds ", sb.st_size));
  if (::close(fd) != 0 && st.ok()) st = WriteError(path, errno, "close failed");
  return st;
}

// fsync of the folder, so the rename itself survives a crash.
void SyncDir(const std::filesystem::path& dir) {
  const int fd = ::open(dir.empty() ? "." : dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) return;
  ::fsync(fd);
  ::close(fd);
}

}  // namespace

void SetWriteFaultForTesting(int64_t fail_after_bytes, int error) {
  g_fail_errno = error;
  g_fail_after = fail_after_bytes;
}

absl::Status WriteArchiveAtomically(const std::filesystem::path& path,
                                    const ArchiveFn& write_archive) {
  const std::filesystem::path tmp = path.string() + ".partial";
  std::error_code ec;
  bool stamped = false;
  absl::Status st = WriteChecked(path, tmp, write_archive, stamped);
  // A file written out of order (OpenVDB's writer seeks back to patch
  // offsets) is read again to stamp its UUID in place (36 bytes, no new
  // blocks), then synced again.
  if (st.ok() && !stamped) st = StampContentUuid(tmp);
  if (st.ok() && !stamped) {
    const int fd = ::open(tmp.c_str(), O_WRONLY | O_CLOEXEC);
    if (fd < 0 || ::fsync(fd) != 0) st = WriteError(path, errno, "fsync failed");
    if (fd >= 0) ::close(fd);
  }
  if (st.ok()) {
    std::filesystem::rename(tmp, path, ec);
    if (ec) st = WriteError(path, ec.value(), "rename failed");
  }
  if (!st.ok()) {
    std::filesystem::remove(tmp, ec);
    return st;
  }
  SyncDir(path.parent_path());
  return absl::OkStatus();
}

absl::Status StampContentUuid(const std::filesystem::path& path) {
  std::fstream f(path, std::ios::in | std::ios::out | std::ios::binary);
  std::string head(kUuidOffset + kUuidSize, '\0');
  if (!f || !f.read(head.data(), std::streamsize(head.size())) || !LooksLikeHeader(head))
    return absl::InternalError(absl::StrCat(path.string(), ": not a VDB file header"));
  Sha256 h;
  h.Update(std::string_view(head).substr(0, kUuidOffset));
  std::string buf(size_t{1} << 20, '\0');
  while (f.read(buf.data(), std::streamsize(buf.size())) || f.gcount() > 0)
    h.Update(std::string_view(buf.data(), size_t(f.gcount())));
  f.clear();
  const std::string uuid = UuidFromDigest(h.HexDigest());
  f.seekp(std::streamoff(kUuidOffset));
  f.write(uuid.data(), std::streamsize(uuid.size()));
  f.close();
  if (!f) return absl::InternalError(absl::StrCat(path.string(), ": cannot stamp the UUID"));
  return absl::OkStatus();
}



}  // namespace nimbus::vdb_internal
