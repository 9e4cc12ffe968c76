// The result store several replicas share: private scratch files per
// writer, results any replica reads, content checked against the hash
// committed beside it, and a running job's files visible everywhere.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <string>

#include "core/base/sha256.h"
#include "server/result_store.h"
#include "tests/support/test_util.h"

namespace nimbus::server {
namespace {

void WriteFile(const std::filesystem::path& p, const std::string& bytes) {
  std::ofstream out(p, std::ios::binary | std::ios::trunc);
  out << bytes;
}

TEST(SharedResultStore, WritersHaveTheirOwnScratchAndReadEachOthersResults) {
  testing::TempDir dir;
  auto a = OpenSharedResultStore(dir / "results", "replica-a");
  auto b = OpenSharedResultStore(dir / "results", "replica/b");  // '/' made plain
  ASSERT_TRUE(a.ok() && b.ok());
  const auto scratch_a = (*a)->ScratchPath("job");
  const auto scratch_b = (*b)->ScratchPath("job");
  EXPECT_NE(scratch_a, scratch_b);
  EXPECT_EQ(scratch_b.parent_path(), scratch_a.parent_path());
  EXPECT_EQ(scratch_b.filename().string().find('/'), std::string::npos);

  WriteFile(scratch_a, "volume bytes");
  auto stored = (*a)->Commit("job", scratch_a);
  ASSERT_TRUE(stored.ok()) << stored.status();
  EXPECT_EQ(stored->sha256, Sha256Hex("volume bytes"));
  auto read = (*b)->Read("job", 0, 100);
  ASSERT_TRUE(read.ok()) << read.status();
  EXPECT_EQ(*read, "volume bytes");
  EXPECT_EQ(*(*b)->Read("job", 7, 100), "bytes");
  EXPECT_EQ(*(*b)->Size("job"), 12u);

  // A second attempt of the same job (identical bytes) commits over it.
  WriteFile(scratch_b, "volume bytes");
  ASSERT_TRUE((*b)->Commit("job", scratch_b).ok());
  EXPECT_EQ(*(*a)->Read("job", 0, 100), "volume bytes");
  EXPECT_FALSE(std::filesystem::exists(scratch_a));
  EXPECT_FALSE(std::filesystem::exists(scratch_b));

  // Deleting frees the result and its hash.
  auto freed = (*a)->Delete("job");
  ASSERT_TRUE(freed.ok());
  EXPECT_EQ((*b)->Read("job", 0, 10).status().code(), absl::StatusCode::kNotFound);
  EXPECT_FALSE(std::filesystem::exists(dir / "results" / "job.vdb.sha256"));
}

TEST(SharedResultStore, DamagedCopyIsDataLoss) {
  testing::TempDir dir;
  auto a = OpenSharedResultStore(dir / "results", "a");
  ASSERT_TRUE(a.ok());
  const auto scratch = (*a)->ScratchPath("job");
  WriteFile(scratch, "the real volume");
  ASSERT_TRUE((*a)->Commit("job", scratch).ok());
  // Same size, other bytes: as a torn write on a network volume would leave.
  WriteFile(dir / "results" / "job.vdb", "the real VOLUME");
  auto read = (*a)->Read("job", 0, 100);
  EXPECT_EQ(read.status().code(), absl::StatusCode::kDataLoss) << read.status();
}

TEST(SharedResultStore, RunningJobsFilesAreListedByEveryReplica) {
  testing::TempDir dir;
  auto a = OpenSharedResultStore(dir / "results", "a");
  auto b = OpenSharedResultStore(dir / "results", "b");
  ASSERT_TRUE(a.ok() && b.ok());
  const auto extra = ExtraFilesDir((*a)->ScratchPath("book"));
  std::filesystem::create_directories(extra);
  WriteFile(extra / "page.0001.vdb", "page one");
  auto files = (*b)->ListFiles("book", /*running=*/true);
  ASSERT_EQ(files.size(), 1u);
  EXPECT_EQ(files[0].name, "page.0001.vdb");
  EXPECT_EQ(files[0].sha256, Sha256Hex("page one"));
  auto page = (*b)->ReadFile("book", "page.0001.vdb", true, 5, 10);
  ASSERT_TRUE(page.ok()) << page.status();
  EXPECT_EQ(*page, "one");
}

}  // namespace
}  // namespace nimbus::server
