#include "server/result_store.h"

#include <algorithm>
#include <fstream>
#include <map>
#include <mutex>
#include <sstream>

#include "absl/strings/str_cat.h"
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
                                      uint64_t max_bytes, const std::string& what) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return absl::NotFoundError(absl::StrCat(what, " is missing from the store"));
  in.seekg(std::streamoff(offset));
  std::string buf(max_bytes, '\0');
  in.read(buf.data(), std::streamsize(max_bytes));
  buf.resize(size_t(in.gcount()));
  return buf;
}

class LocalResultStore : public ResultStore {
 public:
  explicit LocalResultStore(std::filesystem::path dir) : dir_(std::move(dir)) {}

  std::filesystem::path ScratchPath(const std::string& key) override {
    return dir_ / "scratch" / (key + ".partial.vdb");
  }

  absl::StatusOr<StoredResult> Commit(const std::string& key,
                                      const std::filesystem::path& scratch) override {
    auto sha = Sha256File(scratch);
    if (!sha.ok()) return sha.status();
    std::error_code ec;
    const uint64_t size = std::filesystem::file_size(scratch, ec);
    if (ec) return absl::InternalError(absl::StrCat("stat ", scratch.string(), ": ", ec.message()));
    StoredResult result{key, size, *sha, {}};
    const std::filesystem::path extra = ExtraFilesDir(scratch);
    if (std::filesystem::is_directory(extra, ec)) {
      result.files = Scan(extra);
      // The manifest is written before the folder moves, so a committed
      // folder always has one and listing never hashes again.
      std::ofstream m(extra / kManifest, std::ios::trunc);
      for (const StoredFile& f : result.files)
        m << f.name << ' ' << f.size << ' ' << f.sha256 << '\n';
      m.close();
      if (!m) return absl::InternalError(absl::StrCat("cannot write the manifest of ", key));
      std::filesystem::remove_all(FilesDir(key), ec);
      std::filesystem::rename(extra, FilesDir(key), ec);
      if (ec) return absl::InternalError(absl::StrCat("commit files of ", key, ": ", ec.message()));
    }
    std::filesystem::rename(scratch, Path(key), ec);
    if (ec) return absl::InternalError(absl::StrCat("commit ", key, ": ", ec.message()));
    return result;
  }

  absl::StatusOr<std::string> Read(const std::string& key, uint64_t offset,
                                   uint64_t max_bytes) override {
    return ReadRange(Path(key), offset, max_bytes, absl::StrCat("result ", key));
  }

  absl::StatusOr<uint64_t> Size(const std::string& key) override {
    std::error_code ec;
    const uint64_t size = std::filesystem::file_size(Path(key), ec);
    if (ec) return absl::NotFoundError(absl::StrCat("result ", key, " is missing from the store"));
    return size;
  }

  std::vector<StoredFile> ListFiles(const std::string& key, bool running) override {
    if (running) return Scan(ExtraFilesDir(ScratchPath(key)));
    std::vector<StoredFile> files;
    std::ifstream m(FilesDir(key) / kManifest);
    StoredFile f;
    while (m >> f.name >> f.size >> f.sha256) files.push_back(f);
    return files;
  }

  absl::StatusOr<std::string> ReadFile(const std::string& key, const std::string& name,
                                       bool running, uint64_t offset, uint64_t max_bytes) override {
    const std::string what = absl::StrCat("file ", name, " of result ", key);
    if (!IsPlainName(name)) return absl::NotFoundError(absl::StrCat(what, " does not exist"));
    const std::filesystem::path folder = running ? ExtraFilesDir(ScratchPath(key)) : FilesDir(key);
    std::error_code ec;
    if (!std::filesystem::is_regular_file(folder / name, ec))
      return absl::NotFoundError(absl::StrCat(what, " does not exist"));
    return ReadRange(folder / name, offset, max_bytes, what);
  }

 private:
  std::filesystem::path Path(const std::string& key) const { return dir_ / (key + ".vdb"); }
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
  std::mutex mu_;
  std::map<std::string, std::string> sha_cache_;
};

}  // namespace

std::filesystem::path ExtraFilesDir(const std::filesystem::path& scratch) {
  return scratch.string() + ".files";
}

absl::StatusOr<std::unique_ptr<ResultStore>> OpenLocalResultStore(
    const std::filesystem::path& dir) {
  std::error_code ec;
  std::filesystem::create_directories(dir / "scratch", ec);
  if (ec)
    return absl::InternalError(absl::StrCat("cannot create ", dir.string(), ": ", ec.message()));
  return std::unique_ptr<ResultStore>(new LocalResultStore(dir));
}

}  // namespace nimbus::server
