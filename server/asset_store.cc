#include "server/asset_store.h"

#include <atomic>
#include <cctype>

#include "absl/strings/str_cat.h"
#include "proto/asset_paths.h"

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

std::string AssetExtension(const std::string& file_name) {
  std::string ext = std::filesystem::path(file_name).extension().string();
  for (char& c : ext) c = char(std::tolower(static_cast<unsigned char>(c)));
  if (ext == ".obj" || ext == ".ply" || ext == ".stl" || ext == ".vdb") return ext;
  return ".bin";
}

absl::StatusOr<std::unique_ptr<AssetStore>> AssetStore::Open(const std::filesystem::path& dir) {
  std::error_code ec;
  std::filesystem::create_directories(dir / "incoming", ec);
  if (ec)
    return absl::InternalError(absl::StrCat("cannot create ", dir.string(), ": ", ec.message()));
  // Leftovers of uploads cut off by a crash.
  for (std::filesystem::directory_iterator it(dir / "incoming", ec), end; !ec && it != end;
       it.increment(ec))
    std::filesystem::remove(it->path(), ec);
  return std::unique_ptr<AssetStore>(new AssetStore(dir));
}

absl::StatusOr<AssetInfo> AssetStore::Find(const std::string& sha256) const {
  if (!IsHexSha256(sha256))
    return absl::InvalidArgumentError("sha256: must be 64 lower-case hex digits");
  auto path = spec::FindStoredAsset(dir_, sha256);
  if (!path.ok()) return path.status();
  std::error_code ec;
  AssetInfo info{sha256, std::filesystem::file_size(*path, ec), *path, true};
  return info;
}

absl::StatusOr<std::unique_ptr<AssetStore::Upload>> AssetStore::Begin(
    const std::string& sha256, uint64_t size, const std::string& file_name) {
  if (!IsHexSha256(sha256))
    return absl::InvalidArgumentError("sha256: must be 64 lower-case hex digits");
  if (size == 0) return absl::InvalidArgumentError("size_bytes: must be > 0");
  if (size > kMaxAssetBytes)
    return absl::ResourceExhaustedError(
        absl::StrCat("size_bytes: ", size, " exceeds the limit of ", kMaxAssetBytes));
  std::unique_ptr<Upload> u(new Upload());
  u->store_ = this;
  u->sha256_ = sha256;
  u->ext_ = AssetExtension(file_name);
  u->expected_ = size;
  u->tmp_ = dir_ / "incoming" / absl::StrCat(sha256, ".", g_upload_counter++, ".partial");
  u->out_.open(u->tmp_, std::ios::binary | std::ios::trunc);
  if (!u->out_) return absl::InternalError(absl::StrCat("cannot write ", u->tmp_.string()));
  return u;
}

AssetStore::Upload::~Upload() {
  if (done_) return;
  out_.close();
  std::error_code ec;
  std::filesystem::remove(tmp_, ec);
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

absl::StatusOr<AssetInfo> AssetStore::Upload::Finish() {
  out_.close();
  if (received_ != expected_)
    return absl::InvalidArgumentError(
        absl::StrCat("truncated upload: ", received_, " of ", expected_, " bytes arrived"));
  const std::string digest = hash_.HexDigest();
  if (digest != sha256_)
    return absl::DataLossError(
        absl::StrCat("upload hashes to ", digest, ", not the announced ", sha256_));
  if (auto existing = store_->Find(sha256_); existing.ok()) return existing;
  const std::filesystem::path final_path = store_->dir_ / (sha256_ + ext_);
  std::error_code ec;
  std::filesystem::rename(tmp_, final_path, ec);
  if (ec) return absl::InternalError(absl::StrCat("cannot store the asset: ", ec.message()));
  done_ = true;
  return AssetInfo{sha256_, expected_, final_path, false};
}

}  // namespace nimbus::server
