#include "server/result_store.h"

#include <fstream>

#include "absl/strings/str_cat.h"
#include "core/sha256.h"

namespace nimbus::server {

namespace {

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
    std::filesystem::rename(scratch, Path(key), ec);
    if (ec) return absl::InternalError(absl::StrCat("commit ", key, ": ", ec.message()));
    return StoredResult{key, size, *sha};
  }

  absl::StatusOr<std::string> Read(const std::string& key, uint64_t offset,
                                   uint64_t max_bytes) override {
    std::ifstream in(Path(key), std::ios::binary);
    if (!in) return absl::NotFoundError(absl::StrCat("result ", key, " is missing from the store"));
    in.seekg(std::streamoff(offset));
    std::string buf(max_bytes, '\0');
    in.read(buf.data(), std::streamsize(max_bytes));
    buf.resize(size_t(in.gcount()));
    return buf;
  }

  absl::StatusOr<uint64_t> Size(const std::string& key) override {
    std::error_code ec;
    const uint64_t size = std::filesystem::file_size(Path(key), ec);
    if (ec) return absl::NotFoundError(absl::StrCat("result ", key, " is missing from the store"));
    return size;
  }

 private:
  std::filesystem::path Path(const std::string& key) const { return dir_ / (key + ".vdb"); }
  std::filesystem::path dir_;
};

}  // namespace

absl::StatusOr<std::unique_ptr<ResultStore>> OpenLocalResultStore(const std::filesystem::path& dir) {
  std::error_code ec;
  std::filesystem::create_directories(dir / "scratch", ec);
  if (ec) return absl::InternalError(absl::StrCat("cannot create ", dir.string(), ": ", ec.message()));
  return std::unique_ptr<ResultStore>(new LocalResultStore(dir));
}

}  // namespace nimbus::server
