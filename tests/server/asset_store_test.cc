// The content-addressed asset store: only bytes that match the announced
// size and sha256 are ever stored.
#include "server/asset_store.h"

#include <gtest/gtest.h>

#include <gmock/gmock.h>

#include <openvdb/openvdb.h>
#include <openvdb/tools/LevelSetSphere.h>

#include <fstream>

#include "core/base/sha256.h"
#include "core/io/mesh_io.h"
#include "proto/asset_paths.h"
#include "server/untrusted_file.h"
#include "tests/support/test_util.h"
#include "tests/support/vdb_fixtures.h"

namespace nimbus::server {
namespace {


size_t FilesIn(const std::filesystem::path& dir) {
  size_t n = 0;
  for (const auto& e : std::filesystem::directory_iterator(dir)) n += e.is_regular_file();
  return n;
}


absl::StatusOr<AssetInfo> UploadBytes(AssetStore& store, const std::string& bytes,
                                      const std::string& name) {
  auto u = store.Begin(Sha256Hex(bytes), bytes.size(), name);
  if (!u.ok()) return u.status();
  if (auto st = (*u)->Append(bytes); !st.ok()) return st;
  return (*u)->Finish();
}

class AssetStoreTest : public ::testing::Test {
 protected:
  void SetUp() override {
    auto s = AssetStore::Open(dir_.path());
    ASSERT_TRUE(s.ok()) << s.status();
    store_ = std::move(*s);
  }
  testing::TempDir dir_;
  std::unique_ptr<AssetStore> store_;
  const std::string data_ = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";
};

TEST_F(AssetStoreTest, StoresByContentAndRemembersTheName) {
  const std::string sha = Sha256Hex(data_);
  auto u = store_->Begin(sha, data_.size(), "sketches/Sketch.OBJ");
  ASSERT_TRUE(u.ok()) << u.status();
  ASSERT_TRUE((*u)->Append(data_.substr(0, 10)).ok());
  ASSERT_TRUE((*u)->Append(data_.substr(10)).ok());
  auto info = (*u)->Finish();
  ASSERT_TRUE(info.ok()) << info.status();
  EXPECT_FALSE(info->already_present);
  // No format in the stored file's name; the upload's name sits beside it.
  EXPECT_EQ(info->path, dir_.path() / sha);
  EXPECT_EQ(testing::ReadFileBytes(dir_.path() / sha), data_);
  EXPECT_EQ(testing::ReadFileBytes(dir_.path() / (sha + ".names")), "Sketch.OBJ\n");
  EXPECT_EQ(info->names, std::vector<std::string>{"Sketch.OBJ"});
  EXPECT_EQ(info->format, ".obj");
  auto found = store_->Find(sha);
  ASSERT_TRUE(found.ok());
  EXPECT_EQ(found->size, data_.size());
  // A second upload of the same bytes finds the first and adds its name once.
  for (int i = 0; i < 2; ++i) {
    auto again = store_->Begin(sha, data_.size(), "other.obj");
    ASSERT_TRUE((*again)->Append(data_).ok());
    auto info2 = (*again)->Finish();
    ASSERT_TRUE(info2.ok());
    EXPECT_TRUE(info2->already_present);
    EXPECT_EQ(info2->names, (std::vector<std::string>{"Sketch.OBJ", "other.obj"}));
  }
  EXPECT_EQ(FilesIn(dir_.path()), 2u);  // the bytes and the names
  EXPECT_EQ(FilesIn(dir_.path() / "incoming"), 0u);
}

// The reported bug: bytes first uploaded under a name without a known
// extension were stored as <sha>.bin for good, and a later "cow.obj" upload
// answered already_present while the asset stayed unreadable.
TEST_F(AssetStoreTest, ABlobUploadedAgainAsObjBecomesAReadableMesh) {
  const std::string sha = Sha256Hex(data_);
  for (const char* name : {"upload.tmp", "cow.obj"}) {
    auto u = store_->Begin(sha, data_.size(), name);
    ASSERT_TRUE((*u)->Append(data_).ok());
    ASSERT_TRUE((*u)->Finish().ok());
  }
  auto stored = spec::FindStoredAssetInfo(dir_.path(), sha);
  ASSERT_TRUE(stored.ok()) << stored.status();
  EXPECT_EQ(stored->path, dir_.path() / sha);
  EXPECT_EQ(stored->names, (std::vector<std::string>{"upload.tmp", "cow.obj"}));
  EXPECT_EQ(stored->format, ".obj");
  EXPECT_EQ(*spec::FindStoredAsset(dir_.path(), sha), dir_.path() / sha);
  // What the converter does: format from the label, else from the uploads;
  // messages name the label and the hash, never the server's path.
  const std::string label = spec::AssetDisplayName("cow.obj", sha);
  EXPECT_EQ(label, "cow.obj (sha256 " + sha.substr(0, 12) + "...)");
  auto mesh = LoadMesh(stored->path, {MeshFileTypeFromName(spec::AssetFormat("", *stored)), label});
  ASSERT_TRUE(mesh.ok()) << mesh.status();
  EXPECT_EQ(mesh->triangles.size(), 1u);
  // A label with a known extension wins over the upload names.
  EXPECT_EQ(spec::AssetFormat("cow.stl", *stored), ".stl");
  EXPECT_EQ(spec::AssetFormat("my cow", *stored), ".obj");
}

TEST_F(AssetStoreTest, MeshErrorsNameTheLabelNotTheServerPath) {
  const std::string flat = "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n";  // zero area
  const std::string sha = Sha256Hex(flat);
  // Named as a mesh, it is read at upload (in a sandbox) and refused.
  const absl::Status refused = UploadBytes(*store_, flat, "flat.obj").status();
  EXPECT_EQ(refused.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(std::string(refused.message()),
              ::testing::StartsWith("mesh asset flat.obj (sha256 " + sha.substr(0, 12) + "...)"));
  EXPECT_THAT(std::string(refused.message()), ::testing::HasSubstr("degenerate"));
  EXPECT_EQ(std::string(refused.message()).find(dir_.path().string()), std::string::npos);
  // Under a name without a format it is kept, and read as the spec says.
  auto info = UploadBytes(*store_, flat, "flat");
  ASSERT_TRUE(info.ok()) << info.status();
  const std::string label = spec::AssetDisplayName("flat.obj", sha);
  const absl::Status s = LoadMesh(info->path, {MeshFileType::kObj, label}).status();
  const std::string message(s.message());
  EXPECT_THAT(message, ::testing::StartsWith("flat.obj (sha256 " + sha.substr(0, 12) + "...): "));
  EXPECT_THAT(message, ::testing::HasSubstr("degenerate"));
  EXPECT_EQ(message.find(dir_.path().string()), std::string::npos) << message;
  // Without any name the format is unknown, said without a path either.
  const absl::Status unknown = LoadMesh(info->path, {{}, spec::AssetDisplayName("", sha)}).status();
  EXPECT_EQ(std::string(unknown.message()),
            "sha256 " + sha + ": unknown mesh format (expected .obj, .ply or .stl)");
  // A missing hash is named by the hash alone.
  const absl::Status missing = spec::FindStoredAsset(dir_.path(), std::string(64, 'a')).status();
  EXPECT_EQ(missing.code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(std::string(missing.message()), "no stored asset " + std::string(64, 'a'));
}

TEST_F(AssetStoreTest, OldLayoutWithTheExtensionInTheNameIsStillFound) {
  const std::string sha = Sha256Hex(data_);
  std::ofstream(dir_.path() / (sha + ".obj"), std::ios::binary) << data_;
  auto found = store_->Find(sha);
  ASSERT_TRUE(found.ok()) << found.status();
  EXPECT_EQ(found->path, dir_.path() / (sha + ".obj"));
  EXPECT_EQ(found->format, ".obj");
  // An old ".bin" asset takes its format from a later upload's name, and
  // that upload stores nothing new.
  const std::string bin_data = data_ + "# second\n";
  const std::string bin_sha = Sha256Hex(bin_data);
  std::ofstream(dir_.path() / (bin_sha + ".bin"), std::ios::binary) << bin_data;
  EXPECT_EQ(store_->Find(bin_sha)->format, "");
  auto u = store_->Begin(bin_sha, bin_data.size(), "cow.obj");
  ASSERT_TRUE((*u)->Append(bin_data).ok());
  auto info = (*u)->Finish();
  ASSERT_TRUE(info.ok()) << info.status();
  EXPECT_TRUE(info->already_present);
  EXPECT_EQ(info->path, dir_.path() / (bin_sha + ".bin"));
  EXPECT_EQ(info->format, ".obj");
  EXPECT_FALSE(std::filesystem::exists(dir_.path() / bin_sha));
  auto mesh = LoadMesh(info->path, {MeshFileTypeFromName(info->format), "cow.obj"});
  ASSERT_TRUE(mesh.ok()) << mesh.status();
}

TEST_F(AssetStoreTest, HashMismatchIsDataLossAndStoresNothing) {
  const std::string sha = Sha256Hex(data_ + "!");
  auto u = store_->Begin(sha, data_.size(), "a.obj");
  ASSERT_TRUE((*u)->Append(data_).ok());
  EXPECT_EQ((*u)->Finish().status().code(), absl::StatusCode::kDataLoss);
  u->reset();
  EXPECT_EQ(store_->Find(sha).status().code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(FilesIn(dir_.path()), 0u);
  EXPECT_EQ(FilesIn(dir_.path() / "incoming"), 0u);
}

TEST_F(AssetStoreTest, TruncatedAndOverlongUploadsAreRefused) {
  const std::string sha = Sha256Hex(data_);
  auto cut = store_->Begin(sha, data_.size(), "a.obj");
  ASSERT_TRUE((*cut)->Append(data_.substr(0, 5)).ok());
  auto st = (*cut)->Finish().status();
  EXPECT_EQ(st.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(st.message().find("truncated"), std::string::npos) << st;
  cut->reset();
  auto longer = store_->Begin(sha, data_.size(), "a.obj");
  EXPECT_EQ((*longer)->Append(data_ + "extra").code(), absl::StatusCode::kInvalidArgument);
  longer->reset();
  EXPECT_EQ(store_->Find(sha).status().code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(FilesIn(dir_.path() / "incoming"), 0u);
}

TEST_F(AssetStoreTest, RejectsMalformedRequests) {
  EXPECT_EQ(store_->Begin("abc", 3, "a.obj").status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(store_->Begin(std::string(64, 'A'), 3, "a.obj").status().code(),
            absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(store_->Begin(Sha256Hex(data_), 0, "a.obj").status().code(),
            absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(
      store_->Begin(Sha256Hex(data_), AssetStore::kMaxAssetBytes + 1, "a.obj").status().code(),
      absl::StatusCode::kResourceExhausted);
}

TEST(AssetNames, KnownFormatsAndCleanNames) {
  EXPECT_EQ(spec::KnownAssetFormat("cow.obj"), ".obj");
  EXPECT_EQ(spec::KnownAssetFormat("x/y/Mesh.PLY"), ".ply");
  EXPECT_EQ(spec::KnownAssetFormat("bunny.stl"), ".stl");
  EXPECT_EQ(spec::KnownAssetFormat("smoke.vdb"), ".vdb");
  EXPECT_EQ(spec::KnownAssetFormat("notes.txt"), "");
  EXPECT_EQ(spec::KnownAssetFormat("noext"), "");
  EXPECT_EQ(CleanAssetName("/home/ann/cow.obj"), "cow.obj");
  EXPECT_EQ(CleanAssetName("C:\\models\\cow.obj"), "cow.obj");
  EXPECT_EQ(CleanAssetName("a\nb.obj"), "ab.obj");
  EXPECT_EQ(CleanAssetName(".."), "");
  EXPECT_EQ(CleanAssetName(std::string(300, 'x')).size(), 255u);
}


// ---- Poison uploads: read in a sandboxed child, refused, never stored ----

TEST_F(AssetStoreTest, AReadableVdbIsStored) {
  const std::string vdb = testing::SphereVdbBytes(dir_.path() / "sphere-scratch.vdb");
  std::filesystem::remove(dir_.path() / "sphere-scratch.vdb");
  auto info = UploadBytes(*store_, vdb, "sphere.vdb");
  ASSERT_TRUE(info.ok()) << info.status();
  EXPECT_EQ(info->format, ".vdb");
  EXPECT_EQ(testing::ReadFileBytes(info->path), vdb);
}

TEST_F(AssetStoreTest, ATruncatedVdbIsRefusedAndNotStored) {
  const std::string vdb = testing::SphereVdbBytes(dir_.path() / "sphere-scratch.vdb");
  std::filesystem::remove(dir_.path() / "sphere-scratch.vdb");
  const size_t files_before = FilesIn(dir_.path());
  const std::string cut = vdb.substr(0, vdb.size() / 2);
  auto info = UploadBytes(*store_, cut, "cow.vdb");
  ASSERT_EQ(info.status().code(), absl::StatusCode::kInvalidArgument) << info.status();
  const std::string msg(info.status().message());
  EXPECT_THAT(msg, ::testing::StartsWith("grid asset cow.vdb (sha256 " +
                                         Sha256Hex(cut).substr(0, 12) + "...): "
                                         "not a readable VDB file: "));
  EXPECT_LT(msg.size(), 600u);
  EXPECT_EQ(FilesIn(dir_.path()), files_before);
  EXPECT_EQ(store_->Find(Sha256Hex(cut)).status().code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(FilesIn(dir_.path() / "incoming"), 0u);
  // The store still takes good files.
  EXPECT_TRUE(UploadBytes(*store_, vdb, "sphere.vdb").ok());
}

TEST_F(AssetStoreTest, BitFlippedVdbsAreRefusedOrHarmless) {
  const std::string vdb = testing::SphereVdbBytes(dir_.path() / "sphere-scratch.vdb");
  std::filesystem::remove(dir_.path() / "sphere-scratch.vdb");
  // Some flips make OpenVDB allocate without end: a small limit ends those
  // readers sooner than the default would.
  SandboxLimits small;
  small.memory_bytes = 512 << 20;
  auto store = AssetStore::Open(dir_.path() / "small", small);
  ASSERT_TRUE(store.ok()) << store.status();
  int refused = 0;
  // Header, grid descriptor and metadata: lengths, counts and offsets.
  for (size_t offset : {0, 9, 20, 40, 60, 80, 100, 130, 160, 200, 260, 320}) {
    ASSERT_LT(offset, vdb.size());
    std::string flipped = vdb;
    flipped[offset] = char(flipped[offset] ^ 0xff);
    auto info = UploadBytes(**store, flipped, "flip.vdb");
    if (info.ok()) continue;  // a flip in plain data is still a VDB
    ++refused;
    EXPECT_EQ(info.status().code(), absl::StatusCode::kInvalidArgument) << offset;
    EXPECT_THAT(std::string(info.status().message()),
                ::testing::HasSubstr("not a readable VDB file: "));
    EXPECT_LT(info.status().message().size(), 600u);
  }
  EXPECT_GT(refused, 0);
}

TEST_F(AssetStoreTest, GarbageMeshesAreRefused) {
  std::string garbage;
  for (int i = 0; i < 4096; ++i) garbage.push_back(char((i * 131 + 7) & 0xff));
  auto obj = UploadBytes(*store_, garbage, "cow.obj");
  ASSERT_EQ(obj.status().code(), absl::StatusCode::kInvalidArgument) << obj.status();
  EXPECT_THAT(std::string(obj.status().message()),
              ::testing::StartsWith("mesh asset cow.obj (sha256 "));
  EXPECT_THAT(std::string(obj.status().message()),
              ::testing::HasSubstr(": not a readable mesh: "));
  // A PLY header promising two billion vertices is refused, not believed.
  const std::string ply =
      "ply\nformat binary_little_endian 1.0\nelement vertex 2000000000\n"
      "property float x\nproperty float y\nproperty float z\nelement face 1\n"
      "property list uchar int vertex_indices\nend_header\n" + std::string(64, '\0');
  auto big = UploadBytes(*store_, ply, "huge.ply");
  ASSERT_EQ(big.status().code(), absl::StatusCode::kInvalidArgument) << big.status();
  EXPECT_EQ(store_->Find(Sha256Hex(ply)).status().code(), absl::StatusCode::kNotFound);
  // Without a format in its name the bytes are kept: the spec decides.
  EXPECT_TRUE(UploadBytes(*store_, garbage, "blob").ok());
}

TEST(UntrustedFile, LimitsStopAGreedyReader) {
  testing::TempDir dir;
  const std::string vdb = testing::SphereVdbBytes(dir / "sphere.vdb");
  UntrustedFile file{UntrustedKind::kVdbGrid, dir / "sphere.vdb", ".vdb", "", {}};
  EXPECT_TRUE(CheckUntrustedFile(file).ok());
  SandboxLimits tiny;
  tiny.memory_bytes = 16 << 20;  // less than the reader's own program needs
  absl::Status st = CheckUntrustedFile(file, tiny);
  EXPECT_EQ(st.code(), absl::StatusCode::kInvalidArgument) << st;
  EXPECT_THAT(std::string(st.message()), ::testing::StartsWith("not a readable VDB file: "));
}

}  // namespace
}  // namespace nimbus::server
