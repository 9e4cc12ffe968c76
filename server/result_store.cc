#include "server/result_store.h"

#include <fcntl.h>
#include <sys/statvfs.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cstring>
#include <fstream>
#include <functional>
#include <map>
#include <mutex>
#include <optional>
#include <sstream>

#include "absl/strings/str_cat.h"
#include "core/base/file_digests.h"
#include "core/base/sha256.h"

namespace nimbus::server {

namespace {

constexpr char kManifest[] = "MANIFEST";

// A plain file name: no folders, no hidden or partial files.
bool IsPlainName(const std::string& name) {
  return !name.empty() && name[0] != '.' && name.find('/') == std::string::npos &&
         name.find('\\') == std::string::npos && name != kManifest && !name.ends_with(".partial");
}

absl::StatusOr<std::string> ReadRange(const std::filesystem::path& path, uint64_t offset,
                                      uint64_t max_bytes, const std::string& what,
                                      std::string buf) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return absl::NotFoundError(absl::StrCat(what, " is missing from the store"));
  // Growing zero-fills only the new part: a reused buffer costs no memset.
  if (buf.size() < max_bytes) buf.resize(max_bytes);
  size_t got = 0;
  while (got < max_bytes) {
    const ssize_t n = ::pread(fd, buf.data() + got, max_bytes - got, off_t(offset + got));
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) {
      const int err = errno;
      ::close(fd);
      return absl::InternalError(absl::StrCat("read ", what, ": ", std::strerror(err)));
    }
    if (n == 0) break;
    got += size_t(n);
  }
  ::close(fd);
  buf.resize(got);
  return buf;
}

// Writes a small file with every error checked, and fsyncs it.
absl::Status WriteSmallFile(const std::filesystem::path& path, const std::string& bytes) {
  const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) return DiskError(absl::StrCat("create ", path.string()), errno);
  size_t done = 0;
  int err = 0;
  while (done < bytes.size() && err == 0) {
    const ssize_t w = ::write(fd, bytes.data() + done, bytes.size() - done);
    if (w < 0 && errno == EINTR) continue;
    if (w <= 0) err = w < 0 ? errno : ENOSPC;
    else done += size_t(w);
  }
  if (err == 0 && ::fsync(fd) != 0) err = errno;
  if (::close(fd) != 0 && err == 0) err = errno;
  if (err == 0) return absl::OkStatus();
  std::error_code ec;
  std::filesystem::remove(path, ec);
  return DiskError(absl::StrCat("write ", path.string()), err);
}

void SyncDir(const std::filesystem::path& dir) {
  const int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) return;
  ::fsync(fd);
  ::close(fd);
}

class LocalResultStore : public ResultStore {
 public:
  // `writer` empty: this process is the folder's only writer. Otherwise
  // the folder is shared (OpenSharedResultStore) and `writer` names this
  // replica's scratch files.
  LocalResultStore(std::filesystem::path dir, uint64_t min_free_bytes, std::string writer = "")
      : dir_(std::move(dir)), min_free_bytes_(min_free_bytes), writer_(std::move(writer)) {}

  absl::Status CheckFreeSpace() override {
    if (min_free_bytes_ == 0) return absl::OkStatus();
    struct statvfs fs {};
    if (::statvfs(dir_.c_str(), &fs) != 0) return absl::OkStatus();  // unknown: do not refuse
    const uint64_t free_bytes = uint64_t(fs.f_bavail) * uint64_t(fs.f_frsize);
    if (free_bytes >= min_free_bytes_) return absl::OkStatus();
    return absl::ResourceExhaustedError(absl::StrCat(
        "the server's disk is nearly full: ", free_bytes >> 20, " MiB free, below the reserve of ",
        min_free_bytes_ >> 20, " MiB (--min-free-disk-mib); try again later"));
  }

  std::filesystem::path ScratchPath(const std::string& key) override {
    if (writer_.empty()) return dir_ / "scratch" / (key + ".partial.vdb");
    // Two attempts of one job (a replica presumed dead still writing) never
    // share a scratch file.
    return dir_ / "scratch" / (key + "." + writer_ + ".partial.vdb");
  }

  absl::StatusOr<StoredResult> Commit(const std::string& key,
                                      const std::filesystem::path& scratch) override {
    // The VDB writer hashed the file while it synced it; others are read.
    std::optional<std::string> known = RecallFileSha256(scratch);
    absl::StatusOr<std::string> sha =
        known ? absl::StatusOr<std::string>(*std::move(known)) : Sha256File(scratch);
    if (!sha.ok()) return sha.status();
    std::error_code ec;
    const uint64_t size = std::filesystem::file_size(scratch, ec);
    if (ec) return absl::InternalError(absl::StrCat("stat ", scratch.string(), ": ", ec.message()));
    StoredResult result{key, size, *sha, {}};
    if (!writer_.empty()) {
      // The hash goes in first, by rename, so a reader never sees a result
      // without it; attempts of one spec write identical bytes, so either
      // writer's pair is right.
      const std::filesystem::path tmp = dir_ / "scratch" / (key + "." + writer_ + ".sha256");
      if (auto st = WriteSmallFile(tmp, *sha); !st.ok()) return st;
      std::filesystem::rename(tmp, ShaPath(key), ec);
      if (ec) return DiskError(absl::StrCat("commit the hash of ", key), ec.value());
    }
    const std::filesystem::path extra = ExtraFilesDir(scratch);
    const bool has_files = std::filesystem::is_directory(extra, ec);
    if (has_files) {
      result.files = Scan(extra);
      // The manifest is written before the folder moves, so a committed
      // folder always has one and listing never hashes again.
      std::string manifest;
      for (const StoredFile& f : result.files)
        absl::StrAppend(&manifest, f.name, " ", f.size, " ", f.sha256, "\n");
      if (auto st = WriteSmallFile(extra / kManifest, manifest); !st.ok()) return st;
      std::filesystem::remove_all(FilesDir(key), ec);
      std::filesystem::rename(extra, FilesDir(key), ec);
      if (ec) return DiskError(absl::StrCat("commit the files of ", key), ec.value());
    }
    std::filesystem::rename(scratch, Path(key), ec);
    if (ec) {
      // All or nothing: put the files back so no half result is listed.
      std::error_code undo;
      if (has_files) std::filesystem::rename(FilesDir(key), extra, undo);
      return DiskError(absl::StrCat("commit ", key), ec.value());
    }
    SyncDir(dir_);
    return result;
  }

  // Hard links: a cache hit costs no copy, and deleting either job's
  // result leaves the other's (results are never written again).
  absl::StatusOr<StoredResult> CopyResult(const std::string& from_key, const std::string& from_id,
                                          const std::string& to_key) override {
    const std::filesystem::path scratch = ScratchPath(to_key);
    std::error_code ec;
    std::filesystem::create_directories(scratch.parent_path(), ec);
    std::filesystem::remove(scratch, ec);
    std::filesystem::create_hard_link(Path(from_key), scratch, ec);
    if (ec) return ResultStore::CopyResult(from_key, from_id, to_key);  // e.g. no links here
    const std::filesystem::path files = FilesDir(from_id);
    if (std::filesystem::is_directory(files, ec)) {
      const std::filesystem::path extra = ExtraFilesDir(scratch);
      std::filesystem::remove_all(extra, ec);
      std::filesystem::create_directories(extra, ec);
      for (const auto& e : std::filesystem::directory_iterator(files, ec)) {
        // Commit writes its own manifest; a linked one would be rewritten.
        if (e.path().filename() == kManifest) continue;
        std::filesystem::create_hard_link(e.path(), extra / e.path().filename(), ec);
        if (ec) return DiskError(absl::StrCat("link ", e.path().string()), ec.value());
      }
    }
    return Commit(to_key, scratch);
  }

  absl::StatusOr<std::string> Read(const std::string& key, uint64_t offset, uint64_t max_bytes,
                                   std::string buffer) override {
    if (!writer_.empty() && offset == 0) {
      // Another replica wrote it: check it whole before serving the first
      // chunk (a torn or foreign file on a shared volume is caught here).
      if (auto st = VerifyHash(key); !st.ok()) return st;
    }
    return ReadRange(Path(key), offset, max_bytes, absl::StrCat("result ", key),
                     std::move(buffer));
  }

  std::optional<std::filesystem::path> LocalFile(const std::string& key) override {
    if (!IsPlainName(key)) return std::nullopt;
    return Path(key);
  }

  absl::StatusOr<uint64_t> Size(const std::string& key) override {
    std::error_code ec;
    const uint64_t size = std::filesystem::file_size(Path(key), ec);
    if (ec) return absl::NotFoundError(absl::StrCat("result ", key, " is missing from the store"));
    return size;
  }

  absl::StatusOr<uint64_t> Delete(const std::string& key) override {
    if (!IsPlainName(key)) return absl::InvalidArgumentError("bad result key");
    uint64_t freed = 0;
    std::error_code ec;
    for (const std::filesystem::path& p : {Path(key), FilesDir(key), ShaPath(key)}) {
      for (std::filesystem::recursive_directory_iterator it(p, ec), end; !ec && it != end;
           it.increment(ec))
        if (it->is_regular_file(ec)) freed += it->file_size(ec);
      if (std::filesystem::is_regular_file(p, ec)) freed += std::filesystem::file_size(p, ec);
      std::filesystem::remove_all(p, ec);
      if (ec) return absl::InternalError(absl::StrCat("delete ", p.string(), ": ", ec.message()));
    }
    return freed;
  }

  std::vector<StoredFile> ListFiles(const std::string& key, bool running) override {
    if (running) return Scan(RunningFilesDir(key));
    std::vector<StoredFile> files;
    std::ifstream m(FilesDir(key) / kManifest);
    StoredFile f;
    while (m >> f.name >> f.size >> f.sha256) files.push_back(f);
    return files;
  }

  absl::StatusOr<std::string> ReadFile(const std::string& key, const std::string& name,
                                       bool running, uint64_t offset, uint64_t max_bytes,
                                       std::string buffer) override {
    const std::string what = absl::StrCat("file ", name, " of result ", key);
    if (!IsPlainName(name)) return absl::NotFoundError(absl::StrCat(what, " does not exist"));
    const std::filesystem::path folder = running ? RunningFilesDir(key) : FilesDir(key);
    std::error_code ec;
    if (!std::filesystem::is_regular_file(folder / name, ec))
      return absl::NotFoundError(absl::StrCat(what, " does not exist"));
    return ReadRange(folder / name, offset, max_bytes, what, std::move(buffer));
  }

 private:
  std::filesystem::path Path(const std::string& key) const { return dir_ / (key + ".vdb"); }
  std::filesystem::path ShaPath(const std::string& key) const {
    return dir_ / (key + ".vdb.sha256");
  }

  absl::Status VerifyHash(const std::string& key) {
    std::ifstream in(ShaPath(key));
    std::string want;
    if (!(in >> want)) return absl::OkStatus();  // Written before hashes were kept.
    auto got = Sha256File(Path(key));
    if (!got.ok())
      return absl::NotFoundError(absl::StrCat("result ", key, " is missing from the store"));
    if (*got != want)
      return absl::DataLossError(absl::StrCat("result ", key, " does not match its sha256 (", want,
                                              "): the shared results folder holds a damaged copy"));
    return absl::OkStatus();
  }

  // The further files a running job has written so far. In a shared folder
  // the job may run on any replica: the newest attempt's folder wins.
  std::filesystem::path RunningFilesDir(const std::string& key) {
    if (writer_.empty()) return ExtraFilesDir(ScratchPath(key));
    std::filesystem::path best;
    std::filesystem::file_time_type best_time{};
    const std::string prefix = key + ".", suffix = ".partial.vdb.files";
    std::error_code ec;
    for (std::filesystem::directory_iterator it(dir_ / "scratch", ec), end; !ec && it != end;
         it.increment(ec)) {
      const std::string name = it->path().filename().string();
      if (!name.starts_with(prefix) || !name.ends_with(suffix)) continue;
      const auto t = it->last_write_time(ec);
      if (best.empty() || t > best_time) best = it->path(), best_time = t;
    }
    return best.empty() ? ExtraFilesDir(ScratchPath(key)) : best;
  }
  std::filesystem::path FilesDir(const std::string& key) const { return dir_ / (key + ".files"); }

  // Finished files of a folder in name order, hashed once per (name, size,
  // modification time): watchers list a running book's folder often.
  std::vector<StoredFile> Scan(const std::filesystem::path& folder) {
    std::vector<StoredFile> files;
    std::error_code ec;
    for (std::filesystem::directory_iterator it(folder, ec), end; !ec && it != end;
         it.increment(ec)) {
      const std::string name = it->path().filename().string();
      if (!IsPlainName(name) || !it->is_regular_file(ec)) continue;
      StoredFile f;
      f.name = name;
      f.size = it->file_size(ec);
      if (ec) continue;
      const auto mtime = it->last_write_time(ec).time_since_epoch().count();
      const std::string cache_key = absl::StrCat(it->path().string(), "|", f.size, "|", mtime);
      {
        std::lock_guard<std::mutex> lock(mu_);
        if (auto c = sha_cache_.find(cache_key); c != sha_cache_.end()) f.sha256 = c->second;
      }
      if (f.sha256.empty()) {
        auto sha = Sha256File(it->path());
        if (!sha.ok()) continue;
        f.sha256 = *sha;
        std::lock_guard<std::mutex> lock(mu_);
        if (sha_cache_.size() > 100000) sha_cache_.clear();
        sha_cache_[cache_key] = f.sha256;
      }
      files.push_back(std::move(f));
    }
    std::sort(files.begin(), files.end(),
              [](const StoredFile& a, const StoredFile& b) { return a.name < b.name; });
    return files;
  }

  std::filesystem::path dir_;
  uint64_t min_free_bytes_;
  std::string writer_;
  std::mutex mu_;
  std::map<std::string, std::string> sha_cache_;
};

}  // namespace

absl::Status DiskError(const std::string& what, int err) {
  const std::string detail = absl::StrCat(what, ": ", std::strerror(err));
  if (err == ENOSPC || err == EDQUOT)
    return absl::ResourceExhaustedError(
        absl::StrCat("disk full while writing the result: ", detail));
  return absl::InternalError(detail);
}

absl::StatusOr<StoredResult> ResultStore::CopyResult(const std::string& from_key,
                                                     const std::string& from_id,
                                                     const std::string& to_key) {
  constexpr uint64_t kPiece = uint64_t{16} << 20;
  const std::filesystem::path scratch = ScratchPath(to_key);
  std::error_code ec;
  std::filesystem::create_directories(scratch.parent_path(), ec);
  // Streams one file of the result into `path`, piece by piece.
  auto copy = [&](const std::filesystem::path& path,
                  const std::function<absl::StatusOr<std::string>(uint64_t)>& read) {
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    for (uint64_t offset = 0;;) {
      absl::StatusOr<std::string> piece = read(offset);
      if (!piece.ok()) return piece.status();
      if (piece->empty()) break;
      out.write(piece->data(), std::streamsize(piece->size()));
      offset += piece->size();
    }
    out.flush();
    return out ? absl::OkStatus() : DiskError(absl::StrCat("copy into ", path.string()), EIO);
  };
  absl::Status st = copy(scratch, [&](uint64_t o) { return Read(from_key, o, kPiece); });
  if (!st.ok()) return st;
  const std::vector<StoredFile> files = ListFiles(from_id, false);
  if (!files.empty()) std::filesystem::create_directories(ExtraFilesDir(scratch), ec);
  for (const StoredFile& f : files) {
    st = copy(ExtraFilesDir(scratch) / f.name,
              [&](uint64_t o) { return ReadFile(from_id, f.name, false, o, kPiece); });
    if (!st.ok()) return st;
  }
  return Commit(to_key, scratch);
}

std::filesystem::path ExtraFilesDir(const std::filesystem::path& scratch) {
  return scratch.string() + ".files";
}

absl::StatusOr<std::unique_ptr<ResultStore>> OpenLocalResultStore(const std::filesystem::path& dir,
                                                                  uint64_t min_free_bytes) {
  std::error_code ec;
  // An existing store opens on a full disk: start-up writes nothing here.
  if (!std::filesystem::is_directory(dir / "scratch", ec))
    std::filesystem::create_directories(dir / "scratch", ec);
  if (ec)
    return absl::InternalError(absl::StrCat("cannot create ", dir.string(), ": ", ec.message()));
  return std::unique_ptr<ResultStore>(new LocalResultStore(dir, min_free_bytes));
}

absl::StatusOr<std::unique_ptr<ResultStore>> OpenSharedResultStore(
    const std::filesystem::path& dir, const std::string& writer, uint64_t min_free_bytes) {
  // The writer's name becomes part of file names: keep it plain.
  std::string tag = writer.empty() ? std::string("replica") : writer;
  for (char& c : tag)
    if (!std::isalnum(static_cast<unsigned char>(c)) && c != '-' && c != '_') c = '_';
  std::error_code ec;
  if (!std::filesystem::is_directory(dir / "scratch", ec))
    std::filesystem::create_directories(dir / "scratch", ec);
  if (ec)
    return absl::InternalError(absl::StrCat("cannot create ", dir.string(), ": ", ec.message()));
  return std::unique_ptr<ResultStore>(new LocalResultStore(dir, min_free_bytes, tag));
}

}  // namespace nimbus::server
