// The result store on a full disk: Commit is all or nothing, the free-space
// reserve refuses work before the disk fills, and an existing store opens
// without writing.
#include "server/result_store.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <sys/mount.h>

#include <cerrno>
#include <cstring>
#include <fstream>

#include "core/base/sha256.h"
#include "tests/support/test_util.h"

namespace nimbus::server {
namespace {

using ::testing::HasSubstr;

void WriteFile(const std::filesystem::path& p, const std::string& bytes) {
  std::ofstream out(p, std::ios::binary | std::ios::trunc);
  out << bytes;
}

TEST(ResultStoreDisk, CommitMovesFilesAndHashes) {
  testing::TempDir dir;
  auto store = OpenLocalResultStore(dir / "results");
  ASSERT_TRUE(store.ok()) << store.status();
  const auto scratch = (*store)->ScratchPath("job1");
  WriteFile(scratch, "main bytes");
  std::filesystem::create_directories(ExtraFilesDir(scratch));
  WriteFile(ExtraFilesDir(scratch) / "a.0001.vdb", "frame one");
  auto r = (*store)->Commit("job1", scratch);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_EQ(r->size, 10u);
  EXPECT_EQ(r->sha256, Sha256Hex("main bytes"));
  ASSERT_EQ(r->files.size(), 1u);
  EXPECT_EQ(r->files[0].sha256, Sha256Hex("frame one"));
  EXPECT_EQ(*(*store)->Read("job1", 0, 100), "main bytes");
  EXPECT_EQ((*store)->ListFiles("job1", false).size(), 1u);
  EXPECT_FALSE(std::filesystem::exists(scratch));
}

TEST(ResultStoreDisk, ReserveRefusesWorkWhenSpaceIsShort) {
  testing::TempDir dir;
  // No disk has an exabyte free; a reserve of 0 never refuses.
  auto greedy = OpenLocalResultStore(dir / "a", uint64_t{1} << 60);
  ASSERT_TRUE(greedy.ok());
  const absl::Status st = (*greedy)->CheckFreeSpace();
  EXPECT_EQ(st.code(), absl::StatusCode::kResourceExhausted) << st;
  EXPECT_THAT(st.message(), HasSubstr("--min-free-disk-mib"));
  auto none = OpenLocalResultStore(dir / "b", 0);
  ASSERT_TRUE(none.ok());
  EXPECT_TRUE((*none)->CheckFreeSpace().ok());
  auto small = OpenLocalResultStore(dir / "c", 1);
  ASSERT_TRUE(small.ok());
  EXPECT_TRUE((*small)->CheckFreeSpace().ok());
}

// Mounts a tmpfs of `size` at `path` for the test's lifetime.
class Tmpfs {
 public:
  Tmpfs(const std::filesystem::path& path, const char* size) : path_(path) {
    std::filesystem::create_directories(path);
    mounted_ = ::mount("tmpfs", path.c_str(), "tmpfs", 0, size) == 0;
    if (!mounted_) error_ = std::strerror(errno);
  }
  ~Tmpfs() {
    if (mounted_) ::umount2(path_.c_str(), MNT_DETACH);
  }
  bool mounted() const { return mounted_; }
  const std::string& error() const { return error_; }

 private:
  std::filesystem::path path_;
  bool mounted_ = false;
  std::string error_;
};

// Fills the file system holding `dir` to the last byte.
void Fill(const std::filesystem::path& dir) {
  std::ofstream out(dir / "filler", std::ios::binary);
  const std::string block(4096, 'x');
  while (out.write(block.data(), std::streamsize(block.size()))) {
  }
  std::ofstream tail(dir / "filler2", std::ios::binary);
  while (tail.put('x')) tail.flush();
}

TEST(ResultStoreDisk, FullDiskCommitFailsCleanly) {
  testing::TempDir dir;
  Tmpfs fs(dir / "tiny", "size=1m");
  if (!fs.mounted()) GTEST_SKIP() << "cannot mount a tmpfs here (" << fs.error() << ")";
  auto store = OpenLocalResultStore(dir / "tiny" / "results", 512 << 10);
  ASSERT_TRUE(store.ok()) << store.status();
  const auto scratch = (*store)->ScratchPath("job1");
  WriteFile(scratch, "main bytes");
  std::filesystem::create_directories(ExtraFilesDir(scratch));
  WriteFile(ExtraFilesDir(scratch) / "a.0001.vdb", "frame one");
  Fill(dir / "tiny");

  EXPECT_EQ((*store)->CheckFreeSpace().code(), absl::StatusCode::kResourceExhausted);
  auto r = (*store)->Commit("job1", scratch);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), absl::StatusCode::kResourceExhausted) << r.status();
  EXPECT_THAT(r.status().message(), HasSubstr("disk full"));
  // Nothing of the result under its final name; the scratch is intact.
  EXPECT_FALSE((*store)->Size("job1").ok());
  EXPECT_FALSE(std::filesystem::exists(dir / "tiny" / "results" / "job1.vdb"));
  EXPECT_FALSE(std::filesystem::exists(dir / "tiny" / "results" / "job1.files"));
  EXPECT_TRUE(std::filesystem::exists(scratch));

  // The store still opens (start-up writes nothing) and serves reads.
  auto again = OpenLocalResultStore(dir / "tiny" / "results");
  ASSERT_TRUE(again.ok()) << again.status();
  EXPECT_EQ((*again)->Read("job1", 0, 10).status().code(), absl::StatusCode::kNotFound);

  // Space freed: the same commit goes through.
  std::filesystem::remove(dir / "tiny" / "filler");
  auto ok = (*store)->Commit("job1", scratch);
  ASSERT_TRUE(ok.ok()) << ok.status();
  EXPECT_EQ(*(*store)->Read("job1", 0, 100), "main bytes");
}

}  // namespace
}  // namespace nimbus::server
