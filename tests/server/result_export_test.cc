// ExportResult, the embedded server's copy of a result out of the store:
// the exact committed bytes land at the path, and every refusal (unknown
// job, unfinished job, expired result, a store file that no longer matches
// its hash) names the problem and leaves nothing at the path.
#include "server/result_export.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <fstream>

#include "core/base/sha256.h"
#include "tests/support/result_fixtures.h"
#include "tests/support/test_util.h"

namespace nimbus::server {
namespace {

using ::testing::HasSubstr;

constexpr TimeMs kT0 = 1'700'000'000'000;

class ResultExportTest : public testing::LocalStoresTest {
 protected:
  void Create(const std::string& id) {
    NewJob job;
    job.id = id;
    job.name = id;
    job.spec = "spec " + id;
    job.owner = "anonymous";
    ASSERT_TRUE(store_->Create(job, kT0).ok());
  }

  // Runs queued job `id` to success with `bytes` as its committed result.
  void Succeed(const std::string& id, const std::string& bytes) {
    const auto ran = testing::SucceedNext(*store_, *results_, bytes, kT0 + 1);
    ASSERT_TRUE(ran.ok()) << ran.status();
    ASSERT_EQ(*ran, id);
  }

  absl::Status Export(const std::string& id, const std::filesystem::path& path) {
    return ExportResult(*store_, *results_, id, path);
  }
};

TEST_F(ResultExportTest, CopiesTheCommittedBytesOverAnyOldFile) {
  // Over 1 MiB, so the copy takes several chunks; not a multiple of one.
  std::string bytes(3 * (1 << 20) + 12345, '\0');
  for (size_t i = 0; i < bytes.size(); ++i) bytes[i] = char(i * 2654435761u >> 13);
  Create("j1");
  Succeed("j1", bytes);
  const auto out = dir_ / "out.vdb";
  std::ofstream(out) << "an older render";
  ASSERT_TRUE(Export("j1", out).ok());
  EXPECT_EQ(testing::ReadFileBytes(out), bytes);
  EXPECT_FALSE(std::filesystem::exists(out.string() + ".part"));
  // The store keeps its copy.
  EXPECT_EQ(*Sha256File(dir_ / "results" / "j1.vdb"), Sha256Hex(bytes));
}

TEST_F(ResultExportTest, AnEmptyResultIsAnEmptyFile) {
  Create("j1");
  Succeed("j1", "");
  const auto out = dir_ / "empty.vdb";
  ASSERT_TRUE(Export("j1", out).ok());
  EXPECT_TRUE(std::filesystem::exists(out));
  EXPECT_EQ(std::filesystem::file_size(out), 0u);
}

TEST_F(ResultExportTest, RefusesUnknownAndUnfinishedJobs) {
  const auto out = dir_ / "out.vdb";
  absl::Status st = Export("j-none", out);
  EXPECT_EQ(st.code(), absl::StatusCode::kNotFound) << st;
  Create("j1");
  st = Export("j1", out);
  EXPECT_EQ(st.code(), absl::StatusCode::kFailedPrecondition) << st;
  EXPECT_THAT(st.message(), HasSubstr("JOB_STATE_QUEUED"));
  EXPECT_FALSE(std::filesystem::exists(out));
  EXPECT_FALSE(std::filesystem::exists(out.string() + ".part"));
}

TEST_F(ResultExportTest, RefusesAnExpiredResultSayingWhen) {
  Create("j1");
  Succeed("j1", "bytes");
  ASSERT_TRUE(results_->Delete("j1").ok());
  ASSERT_TRUE(store_->MarkResultExpired("j1", kT0 + 5000).ok());
  const absl::Status st = ExportResult(*store_, *results_, "j1", dir_ / "o.vdb", 3'600'000);
  EXPECT_EQ(st.code(), absl::StatusCode::kFailedPrecondition) << st;
  EXPECT_THAT(st.message(), HasSubstr("expired"));
  EXPECT_THAT(st.message(), HasSubstr("keeps results 3600 s"));
}

TEST_F(ResultExportTest, AStoreFileThatNoLongerMatchesItsHashIsDataLoss) {
  Create("j1");
  Succeed("j1", "the committed bytes");
  // Same size, one byte flipped on disk after the commit.
  std::ofstream(dir_ / "results" / "j1.vdb", std::ios::binary) << "the committed bytez";
  const auto out = dir_ / "out.vdb";
  std::ofstream(out) << "keep me";
  const absl::Status st = Export("j1", out);
  EXPECT_EQ(st.code(), absl::StatusCode::kDataLoss) << st;
  EXPECT_THAT(st.message(), HasSubstr("sha256 mismatch"));
  EXPECT_EQ(testing::ReadFileBytes(out), "keep me");
  EXPECT_FALSE(std::filesystem::exists(out.string() + ".part"));
}

TEST_F(ResultExportTest, AShortStoreFileIsDataLoss) {
  Create("j1");
  Succeed("j1", "the committed bytes");
  std::ofstream(dir_ / "results" / "j1.vdb", std::ios::binary) << "the comm";
  const absl::Status st = Export("j1", dir_ / "out.vdb");
  EXPECT_EQ(st.code(), absl::StatusCode::kDataLoss) << st;
  EXPECT_THAT(st.message(), HasSubstr("ends at 8 of 19 bytes"));
  EXPECT_FALSE(std::filesystem::exists(dir_ / "out.vdb"));
}

TEST_F(ResultExportTest, AnUnwritableFolderIsNamed) {
  Create("j1");
  Succeed("j1", "bytes");
  const absl::Status st = Export("j1", dir_ / "no" / "such" / "dir" / "out.vdb");
  EXPECT_EQ(st.code(), absl::StatusCode::kPermissionDenied) << st;
  EXPECT_THAT(st.message(), HasSubstr("no/such/dir/out.vdb.part"));
}

}  // namespace
}  // namespace nimbus::server
