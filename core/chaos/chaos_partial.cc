#include "core/chaos/chaos_partial.h"

#include <cstdio>
#include <cstring>
#include <fstream>
#include <iterator>
#include <memory>
#include <vector>

#include "absl/strings/str_cat.h"
#include "core/base/sha256.h"

namespace nimbus {

namespace {

constexpr char kMagic[8] = {'N', 'I', 'M', 'B', 'U', 'S', 'C', 'P'};
// 2: grids one voxel thick are stored folded (CountGrid), so format 1's
// tiles of such grids mean other voxels.
constexpr uint32_t kFormatVersion = 2;
constexpr size_t kDigestBytes = 64;  // hex SHA-256

static_assert(__BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__, "partials are written little-endian");

struct Header {
  char magic[8];
  uint32_t version;
  int32_t res[3];
  uint32_t with_color;
  uint32_t reserved;
  uint64_t stats[4];  // iterations_done, outside, reseeded, final_nonfinite
  uint64_t tiles;
};
static_assert(sizeof(Header) == 72);

// A file written through a hash, so the digest costs no second read.
class HashedWriter {
 public:
  explicit HashedWriter(std::FILE* f) : f_(f) {}
  void Write(const void* data, size_t n) {
    hash_.Update(std::string_view(static_cast<const char*>(data), n));
    ok_ = ok_ && std::fwrite(data, 1, n, f_) == n;
  }
  bool Finish() {
    const std::string digest = hash_.HexDigest();
    ok_ = ok_ && std::fwrite(digest.data(), 1, digest.size(), f_) == digest.size();
    return ok_;
  }

 private:
  std::FILE* f_;
  Sha256 hash_;
  bool ok_ = true;
};

bool AllZero(const uint32_t* t) {
  for (int i = 0; i < CountGrid::kTileVoxels; ++i)
    if (t[i] != 0) return false;
  return true;
}

absl::Status Damaged(const std::string& why) {
  return absl::DataLossError(absl::StrCat("chaos partial: ", why));
}

}  // namespace

absl::Status SaveChaosPartial(const std::filesystem::path& path, const CountGrid& counts,
                              const ChaosGameStats& stats) {
  Header h{};
  std::memcpy(h.magic, kMagic, sizeof kMagic);
  h.version = kFormatVersion;
  const Int3 r = counts.resolution();
  h.res[0] = r.x, h.res[1] = r.y, h.res[2] = r.z;
  h.with_color = counts.has_color() ? 1 : 0;
  h.stats[0] = stats.iterations_done, h.stats[1] = stats.outside;
  h.stats[2] = stats.reseeded, h.stats[3] = stats.final_nonfinite;
  counts.ForEachTile([&](Int3, const uint32_t* t) { h.tiles += !AllZero(t); });
  std::unique_ptr<std::FILE, int (*)(std::FILE*)> f(std::fopen(path.c_str(), "wb"), &std::fclose);
  if (!f) return absl::InternalError(absl::StrCat("cannot create the partial ", path.string()));
  HashedWriter w(f.get());
  w.Write(&h, sizeof h);
  const Int3 tiles = counts.tiles();
  counts.ForEachTileWithColor([&](Int3 o, const uint32_t* t, const uint64_t* c) {
    if (AllZero(t)) return;
    const uint64_t index = (uint64_t(o.x / CountGrid::kTileDim) * tiles.y +
                            uint64_t(o.y / CountGrid::kTileDim)) * tiles.z +
                           uint64_t(o.z / CountGrid::kTileDim);
    w.Write(&index, sizeof index);
    w.Write(t, sizeof(uint32_t) * CountGrid::kTileVoxels);
    if (c) w.Write(c, sizeof(uint64_t) * CountGrid::kTileVoxels);
  });
  if (!w.Finish() || std::fflush(f.get()) != 0)
    return absl::ResourceExhaustedError(absl::StrCat("cannot write the partial ", path.string()));
  return absl::OkStatus();
}

absl::Status AddChaosPartial(std::string_view bytes, CountGrid& counts, ChaosGameStats& stats) {
  if (bytes.size() < sizeof(Header) + kDigestBytes) return Damaged("too short");
  const std::string_view body = bytes.substr(0, bytes.size() - kDigestBytes);
  if (Sha256Hex(body) != bytes.substr(body.size())) return Damaged("checksum mismatch");
  Header h;
  std::memcpy(&h, body.data(), sizeof h);
  if (std::memcmp(h.magic, kMagic, sizeof kMagic) != 0 || h.version != kFormatVersion)
    return Damaged(absl::StrCat("not a chaos partial of format ", kFormatVersion));
  const Int3 r = counts.resolution();
  if (h.res[0] != r.x || h.res[1] != r.y || h.res[2] != r.z ||
      (h.with_color != 0) != counts.has_color())
    return absl::InvalidArgumentError("chaos partial: made for another grid");
  const size_t tile_bytes = sizeof(uint64_t) + sizeof(uint32_t) * CountGrid::kTileVoxels +
                            (h.with_color ? sizeof(uint64_t) * CountGrid::kTileVoxels : 0);
  if (h.tiles > counts.TileCount() || body.size() != sizeof h + h.tiles * tile_bytes)
    return Damaged("size does not match its tile count");
  // Copies keep the tile data aligned whatever the buffer's alignment.
  std::vector<uint32_t> t(CountGrid::kTileVoxels);
  std::vector<uint64_t> c(h.with_color ? CountGrid::kTileVoxels : 0);
  const char* p = body.data() + sizeof h;
  for (uint64_t i = 0; i < h.tiles; ++i) {
    uint64_t index;
    std::memcpy(&index, p, sizeof index);
    p += sizeof index;
    if (index >= counts.TileCount()) return Damaged("tile index out of range");
    std::memcpy(t.data(), p, t.size() * sizeof(uint32_t));
    p += t.size() * sizeof(uint32_t);
    if (h.with_color) {
      std::memcpy(c.data(), p, c.size() * sizeof(uint64_t));
      p += c.size() * sizeof(uint64_t);
    }
    counts.AddTile(index, t.data(), h.with_color ? c.data() : nullptr);
  }
  stats.iterations_done += h.stats[0];
  stats.outside += h.stats[1];
  stats.reseeded += h.stats[2];
  stats.final_nonfinite += h.stats[3];
  return absl::OkStatus();
}

absl::Status AddChaosPartialFile(const std::filesystem::path& path, CountGrid& counts,
                                 ChaosGameStats& stats) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return absl::NotFoundError(absl::StrCat("cannot open the partial ", path.string()));
  const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  return AddChaosPartial(bytes, counts, stats);
}

}  // namespace nimbus
