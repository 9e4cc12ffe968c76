// The content-addressed asset store: only bytes that match the announced
// size and sha256 are ever stored.
#include "server/asset_store.h"

#include <gtest/gtest.h>

#include "core/base/sha256.h"
#include "tests/support/test_util.h"

namespace nimbus::server {
namespace {

size_t FilesIn(const std::filesystem::path& dir) {
  size_t n = 0;
  for (const auto& e : std::filesystem::directory_iterator(dir)) n += e.is_regular_file();
  return n;
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

TEST_F(AssetStoreTest, StoresByHashKeepingTheExtension) {
  const std::string sha = Sha256Hex(data_);
  auto u = store_->Begin(sha, data_.size(), "Sketch.OBJ");
  ASSERT_TRUE(u.ok()) << u.status();
  ASSERT_TRUE((*u)->Append(data_.substr(0, 10)).ok());
  ASSERT_TRUE((*u)->Append(data_.substr(10)).ok());
  auto info = (*u)->Finish();
  ASSERT_TRUE(info.ok()) << info.status();
  EXPECT_FALSE(info->already_present);
  EXPECT_EQ(info->path, dir_.path() / (sha + ".obj"));
  auto found = store_->Find(sha);
  ASSERT_TRUE(found.ok());
  EXPECT_EQ(found->size, data_.size());
  // A second upload of the same bytes finds the first.
  auto again = store_->Begin(sha, data_.size(), "other.obj");
  ASSERT_TRUE((*again)->Append(data_).ok());
  auto info2 = (*again)->Finish();
  ASSERT_TRUE(info2.ok());
  EXPECT_TRUE(info2->already_present);
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

TEST(AssetExtension, KnownFormatsOnly) {
  EXPECT_EQ(AssetExtension("cow.obj"), ".obj");
  EXPECT_EQ(AssetExtension("x/y/Mesh.PLY"), ".ply");
  EXPECT_EQ(AssetExtension("bunny.stl"), ".stl");
  EXPECT_EQ(AssetExtension("smoke.vdb"), ".vdb");
  EXPECT_EQ(AssetExtension("notes.txt"), ".bin");
  EXPECT_EQ(AssetExtension("noext"), ".bin");
}

}  // namespace
}  // namespace nimbus::server
