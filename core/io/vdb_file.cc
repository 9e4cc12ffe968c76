#include "core/io/vdb_file.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cstring>
#include <new>
#include <string_view>
#include <system_error>
#include <thread>
#include <vector>

#include "absl/strings/str_cat.h"
#include "core/base/file_digests.h"
#include "core/base/sha256.h"

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
// internal error; both name the file, never its folder.
absl::Status WriteError(const std::filesystem::path& path, int err, const std::string& what) {
  const std::string detail =
      absl::StrCat(path.filename().string(), ": ", what, ": ", std::strerror(err));
  if (err == ENOSPC || err == EDQUOT)
    return absl::ResourceExhaustedError(
        absl::StrCat("disk full while writing the result: ", detail));
  return absl::InternalError(absl::StrCat("cannot write the result: ", detail));
}

// A seekable output buffer over a file descriptor that keeps the first
// write error: std::ofstream (and so openvdb::io::File) loses errno and
// OpenVDB never checks the stream, so a full disk would leave a short file
// that looked written.
//
// It also hashes the archive as it goes out (WriteLog), so the content
// UUID needs no second reading of the file.
class CheckedFileBuf : public std::streambuf {
 public:
  explicit CheckedFileBuf(int fd) : fd_(fd), buf_(size_t{1} << 16) {
    setp(buf_.data(), buf_.data() + buf_.size());
  }
  int error() const { return error_; }
  uint64_t end() const { return end_; }
  /// The digest of every write so far: see WriteLog.
  std::string LogDigest() { return log_.HexDigest(); }
  bool Flush() {
    const char* p = pbase();
    size_t n = size_t(pptr() - pbase());
    setp(buf_.data(), buf_.data() + buf_.size());
    if (n > 0 && error_ == 0) WriteLog(pos_, std::string_view(p, n));
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
  // Asks the kernel to start writing each few MiB out while the rest is
  // still being encoded, so the final fsync waits for the last of them
  // only. Advice: a failure here shows in the fsync.
  void StartWriteback() {
    constexpr uint64_t kStep = uint64_t{4} << 20;
    if (pos_ < started_ + kStep) return;
    ::sync_file_range(fd_, off_t(started_), off_t(pos_ - started_), SYNC_FILE_RANGE_WRITE);
    started_ = pos_;
  }

  // Each write in order: its offset (8 bytes, little-endian) and its bytes,
  // less any part of the UUID field. OpenVDB writes an archive the same way
  // every time (forward, then a few patches of grid offsets), so the same
  // grids give the same log.
  void WriteLog(uint64_t at, std::string_view bytes) {
    unsigned char offset[8];
    for (int i = 0; i < 8; ++i) offset[i] = (unsigned char)(at >> (8 * i));
    log_.Update(std::string_view(reinterpret_cast<const char*>(offset), sizeof(offset)));
    const uint64_t end = at + bytes.size();
    const uint64_t cut_begin = std::clamp<uint64_t>(kUuidOffset, at, end);
    const uint64_t cut_end = std::clamp<uint64_t>(kUuidOffset + kUuidSize, at, end);
    log_.Update(bytes.substr(0, cut_begin - at));
    log_.Update(bytes.substr(cut_end - at));
  }

  int fd_;
  Sha256 log_;
  uint64_t started_ = 0;  // writeback was started below this offset
  std::vector<char> buf_;
  int error_ = 0;
  uint64_t pos_ = 0, end_ = 0;
};

// Writes the UUID made from `digest` into the VDB file open as `fd`.
// Returns errno on failure (EINVAL: no VDB header).
int StampUuidFromDigest(int fd, const std::string& digest) {
  std::string head(kUuidOffset + kUuidSize, '\0');
  if (::pread(fd, head.data(), head.size(), 0) != ssize_t(head.size()) || !LooksLikeHeader(head))
    return EINVAL;
  const std::string uuid = UuidFromDigest(digest);
  if (::pwrite(fd, uuid.data(), uuid.size(), off_t(kUuidOffset)) != ssize_t(uuid.size()))
    return errno != 0 ? errno : EIO;
  return 0;
}

// Replaces the UUID of the VDB file open as `fd` with its content UUID.
// Returns errno on failure (EINVAL: no VDB header).
int StampUuid(int fd) {
  std::string head(kUuidOffset + kUuidSize, '\0');
  if (::pread(fd, head.data(), head.size(), 0) != ssize_t(head.size()) || !LooksLikeHeader(head))
    return EINVAL;
  Sha256 h;
  h.Update(std::string_view(head).substr(0, kUuidOffset));
  std::vector<char> buf(size_t{1} << 20);
  for (off_t at = off_t(head.size());;) {
    const ssize_t n = ::pread(fd, buf.data(), buf.size(), at);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) return errno;
    if (n == 0) break;
    h.Update(std::string_view(buf.data(), size_t(n)));
    at += n;
  }
  return StampUuidFromDigest(fd, h.HexDigest());
}

std::atomic<DigestSink> g_digest_sink{&RememberFileSha256};

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
  if (sha.ok()) g_digest_sink.load()(fd, *sha);
  return absl::OkStatus();
}

// Writes the archive to `tmp`, stamps its content UUID, fsyncs it (while
// hashing it for the result store) and checks its size on disk.
absl::Status WriteChecked(const std::filesystem::path& path, const std::filesystem::path& tmp,
                          const ArchiveFn& write_archive) {
  const int fd = ::open(tmp.c_str(), O_RDWR | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) return WriteError(path, errno, "cannot create " + tmp.filename().string());
  CheckedFileBuf buf(fd);
  std::ostream os(&buf);
  absl::Status st;
  try {
    write_archive(os);
    os.flush();
  } catch (const std::exception& e) {
    if (buf.error() == 0)
      st = absl::InternalError(absl::StrCat("writing ", path.filename().string(), ": ", e.what()));
  }
  buf.Flush();
  if (st.ok() && buf.error() != 0) st = WriteError(path, buf.error(), "write failed");
  if (st.ok()) {
    if (const int err = StampUuidFromDigest(fd, buf.LogDigest()); err != 0)
      st = WriteError(path, err, "cannot stamp the UUID");
  }
  if (st.ok()) st = SyncWhileHashing(fd, tmp, path);
  struct stat sb {};
  if (st.ok() && (::fstat(fd, &sb) != 0 || uint64_t(sb.st_size) != buf.end()))
    st = absl::InternalError(absl::StrCat("writing ", path.filename().string(), ": ", buf.end(),
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

void SetDigestSink(DigestSink sink) { g_digest_sink = sink ? sink : &RememberFileSha256; }

absl::Status WriteArchiveAtomically(const std::filesystem::path& path,
                                    const ArchiveFn& write_archive) {
  const std::filesystem::path tmp = path.string() + ".partial";
  std::error_code ec;
  absl::Status st = WriteChecked(path, tmp, write_archive);
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
  const int fd = ::open(path.c_str(), O_RDWR | O_CLOEXEC);
  const int err = fd < 0 ? errno : StampUuid(fd);
  if (fd >= 0) ::close(fd);
  if (err != 0)
    return absl::InternalError(absl::StrCat(path.filename().string(), ": cannot stamp the UUID: ",
                                            err == EINVAL ? "not a VDB file header"
                                                          : std::strerror(err)));
  return absl::OkStatus();
}

}  // namespace nimbus::vdb_internal
