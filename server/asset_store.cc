#include "server/asset_store.h"

#include <unistd.h>

#include <atomic>
#include <fstream>

#include "absl/strings/str_cat.h"
#include "proto/asset_paths.h"
#include "server/untrusted_file.h"

namespace nimbus::server {

namespace {

bool IsHexSha256(const std::string& s) {
  if (s.size() != 64) return false;
  for (char c : s)
    if (!((c >= '0' && c <= '9') || (c >= 'a' && c <= 'f'))) return false;
  return true;
}

std::atomic<uint64_t> g_upload_counter{0};

}  // namespace

std::string CleanAssetName(const std::string& file_name) {
  // Only the name part: a client's folders say nothing about the content.
  const size_t slash = file_name.find_last_of("/\\");
  std::string name = slash == std::string::npos ? file_name : file_name.substr(slash + 1);
  std::erase_if(name, [](char c) { return static_cast<unsigned char>(c) < 0x20 || c == 0x7f; });
  if (name.size() > 255) name.resize(255);
  if (name == "." || name == "..") name.clear();
  return name;
}

absl::StatusOr<std::unique_ptr<AssetStore>> AssetStore::Open(const std::filesystem::path& dir,
                                                             SandboxLimits sandbox) {
  std::error_code ec;
  std::filesystem::create_directories(dir / "incoming", ec);
  if (ec)
    return absl::InternalError(absl::StrCat("cannot create ", dir.string(), ": ", ec.message()));
  // Leftovers of uploads cut off by a crash.
  for (std::filesystem::directory_iterator it(dir / "incoming", ec), end; !ec && it != end;
       it.increment(ec))
    std::filesystem::remove(it->path(), ec);
  return std::unique_ptr<AssetStore>(new AssetStore(dir, sandbox));
}

absl::StatusOr<AssetInfo> AssetStore::Find(const std::string& sha256) const {
  if (!IsHexSha256(sha256))
    return absl::InvalidArgumentError("sha256: must be 64 lower-case hex digits");
  auto stored = spec::FindStoredAssetInfo(dir_, sha256);
  if (!stored.ok()) return stored.status();
  std::error_code ec;
  AssetInfo info;
  info.sha256 = sha256;
  info.size = std::filesystem::file_size(stored->path, ec);
  info.path = stored->path;
  info.already_present = true;
  info.names = std::move(stored->names);
  info.format = std::move(stored->format);
  return info;
}

absl::Status AssetStore::RememberLine(const std::filesystem::path& path, const std::string& sha256,
                                      const std::string& line) {
  if (line.empty()) return absl::OkStatus();
  std::lock_guard<std::mutex> lock(names_mu_);
  std::string text;
  size_t count = 0;
  {
    std::ifstream in(path);
    for (std::string old; std::getline(in, old);) {
      if (old == line) return absl::OkStatus();
      text += old + "\n";
      ++count;
    }
  }
  if (count >= kMaxNames) return absl::OkStatus();
  text += line + "\n";
  // Rewritten whole and renamed, so a reader never sees half a line.
  const std::filesystem::path tmp =
      dir_ / "incoming" /
      absl::StrCat(sha256, ".sidecar.", ::getpid(), ".", g_upload_counter++, ".partial");
  std::ofstream out(tmp, std::ios::trunc);
  out << text;
  out.close();
  std::error_code ec;
  if (out) std::filesystem::rename(tmp, path, ec);
  if (!out || ec) {
    std::filesystem::remove(tmp, ec);
    return absl::InternalError(absl::StrCat("cannot record ", path.filename().string()));
  }
  return absl::OkStatus();
}

absl::Status AssetStore::AddOwner(const std::string& sha256, const std::string& principal) {
  auto info = Find(sha256);
  if (!info.ok()) return info.status();
  std::error_code ec;
  std::filesystem::last_write_time(info->path, std::filesystem::file_time_type::clock::now(), ec);
  return RememberLine(OwnersPath(sha256), sha256, principal);
}

bool AssetStore::IsOwner(const std::string& sha256, const std::string& principal) const {
  if (!IsHexSha256(sha256)) return false;
  std::ifstream in(OwnersPath(sha256));
  for (std::string line; std::getline(in, line);)
    if (line == principal) return true;
  return false;
}

uint64_t AssetStore::OwnedBytes(const std::string& principal) const {
  uint64_t total = 0;
  std::error_code ec;
  for (std::filesystem::directory_iterator it(dir_, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string file = it->path().filename().string();
    if (!file.ends_with(".owners")) continue;
    const std::string sha256 = file.substr(0, file.size() - 7);
    if (!IsOwner(sha256, principal)) continue;
    if (auto info = Find(sha256); info.ok()) total += info->size;
  }
  return total;
}

int AssetStore::ExpireUnreferenced(std::filesystem::file_time_type cutoff,
                                   const std::set<std::string>& keep) {
  int removed = 0;
  std::error_code ec;
  std::vector<std::filesystem::path> doomed;
  for (std::filesystem::directory_iterator it(dir_, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string file = it->path().filename().string();
    const std::string sha256 = file.substr(0, 64);
    // The bytes: <sha256>, or <sha256><ext> in data dirs of the older layout.
    const bool bytes =
        IsHexSha256(sha256) &&
        (file.size() == 64 || !spec::KnownAssetFormat(file).empty() || file.ends_with(".bin"));
    if (!bytes || keep.count(sha256) || !it->is_regular_file(ec)) continue;
    if (it->last_write_time(ec) >= cutoff || ec) continue;
    doomed.push_back(it->path());
  }
  for (const std::filesystem::path& path : doomed) {
    const std::string sha256 = path.filename().string().substr(0, 64);
    std::lock_guard<std::mutex> lock(names_mu_);
    if (!std::filesystem::remove(path, ec)) continue;
    std::filesystem::remove(spec::StoredAssetNamesPath(dir_, sha256), ec);
    std::filesystem::remove(OwnersPath(sha256), ec);
    std::filesystem::remove(spec::LaunderedPath(path), ec);
    ++removed;
  }
  return removed;
}

absl::StatusOr<std::unique_ptr<AssetStore::Upload>> AssetStore::Begin(const std::string& sha256,
                                                                      uint64_t size,
                                                                      const std::string& file_name,
                                                                      const std::string& owner) {
  if (!IsHexSha256(sha256))
    return absl::InvalidArgumentError("sha256: must be 64 lower-case hex digits");
  if (size == 0) return absl::InvalidArgumentError("size_bytes: must be > 0");
  if (size > kMaxAssetBytes)
    return absl::ResourceExhaustedError(
        absl::StrCat("size_bytes: ", size, " exceeds the limit of ", kMaxAssetBytes));
  std::unique_ptr<Upload> u(new Upload());
  u->store_ = this;
  u->sha256_ = sha256;
  u->name_ = CleanAssetName(file_name);
  u->owner_ = owner;
  u->expected_ = size;
  // The pid keeps replicas sharing the folder apart.
  u->tmp_ = dir_ / "incoming" /
            absl::StrCat(sha256, ".", ::getpid(), ".", g_upload_counter++, ".partial");
  u->out_.open(u->tmp_, std::ios::binary | std::ios::trunc);
  if (!u->out_) return absl::InternalError(absl::StrCat("cannot write ", u->tmp_.string()));
  return u;
}

AssetStore::Upload::~Upload() {
  if (done_) return;
  out_.close();
  std::error_code ec;
  std::filesystem::remove(tmp_, ec);
  std::filesystem::remove(spec::LaunderedPath(tmp_), ec);
}

absl::Status AssetStore::Upload::Append(const std::string& data) {
  if (received_ + data.size() > expected_)
    return absl::InvalidArgumentError(
        absl::StrCat("upload is longer than the announced ", expected_, " bytes"));
  hash_.Update(data);
  out_.write(data.data(), std::streamsize(data.size()));
  if (!out_) return absl::InternalError("cannot write the upload");
  received_ += data.size();
  return absl::OkStatus();
}

absl::Status AssetStore::Upload::CheckContent() const {
  // A name without a known format says nothing of the content; the spec
  // that uses the asset decides, and submit checks it then.
  const std::string format = spec::KnownAssetFormat(name_);
  if (format.empty()) return absl::OkStatus();
  UntrustedFile file;
  file.kind = format == ".vdb" ? UntrustedKind::kVdbGrid : UntrustedKind::kMesh;
  file.path = tmp_;
  file.format = format;
  absl::Status st = CheckStoredAsset(sha256_, file, store_->sandbox_);
  if (!absl::IsInvalidArgument(st)) return st;
  return absl::InvalidArgumentError(
      absl::StrCat(file.kind == UntrustedKind::kVdbGrid ? "grid asset " : "mesh asset ",
                   spec::AssetDisplayName(name_, sha256_), ": ", st.message()));
}

absl::StatusOr<AssetInfo> AssetStore::Upload::Finish() {
  out_.close();
  if (received_ != expected_)
    return absl::InvalidArgumentError(
        absl::StrCat("truncated upload: ", received_, " of ", expected_, " bytes arrived"));
  const std::string digest = hash_.HexDigest();
  if (digest != sha256_)
    return absl::DataLossError(
        absl::StrCat("upload hashes to ", digest, ", not the announced ", sha256_));
  if (auto st = CheckContent(); !st.ok()) return st;
  bool fresh = false;
  std::error_code ec;
  // Same bytes, same file: a second upload only adds its name.
  if (!store_->Find(sha256_).ok()) {
    std::filesystem::rename(tmp_, store_->dir_ / sha256_, ec);
    if (ec) return absl::InternalError(absl::StrCat("cannot store the asset: ", ec.message()));
    // The checker's copy of a grid moves with it (FindStoredAsset's path).
    std::filesystem::rename(spec::LaunderedPath(tmp_),
                            spec::LaunderedPath(store_->dir_ / sha256_), ec);
    done_ = true;
    fresh = true;
  }
  if (auto st =
          store_->RememberLine(spec::StoredAssetNamesPath(store_->dir_, sha256_), sha256_, name_);
      !st.ok())
    return st;
  // Bytes only another principal uploaded answer as a first upload would:
  // the answer must not tell a caller what others have stored.
  const bool had_it = !fresh && (owner_.empty() || store_->IsOwner(sha256_, owner_));
  if (!owner_.empty())
    if (auto st = store_->AddOwner(sha256_, owner_); !st.ok()) return st;
  auto info = store_->Find(sha256_);
  if (!info.ok()) return info.status();
  info->already_present = had_it;
  return info;
}

}  // namespace nimbus::server
