// ExportResult, the embedded server's copy of a result out of the store:
// the exact committed bytes land at the path, and every refusal (unknown
// job, unfinished job, expired result, a store file that no longer matches
// its hash) names the problem and leaves nothing at the path.
#include "server/result_export.h"

#include <fcntl.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <fstream>
#include <optional>

#include "core/base/file_digests.h"
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

// The local store, counting the reads that go through it.
class CountingStore : public ResultStore {
 public:
  explicit CountingStore(ResultStore& s) : s_(s) {}
  int reads = 0;
  std::filesystem::path ScratchPath(const std::string& key) override { return s_.ScratchPath(key); }
  absl::StatusOr<StoredResult> Commit(const std::string& key,
                                      const std::filesystem::path& scratch) override {
    return s_.Commit(key, scratch);
  }
  absl::StatusOr<std::string> Read(const std::string& key, uint64_t offset, uint64_t max_bytes,
                                   std::string buffer) override {
    ++reads;
    return s_.Read(key, offset, max_bytes, std::move(buffer));
  }
  absl::StatusOr<uint64_t> Size(const std::string& key) override { return s_.Size(key); }
  std::optional<std::filesystem::path> LocalFile(const std::string& key) override {
    return s_.LocalFile(key);
  }
  absl::StatusOr<uint64_t> Delete(const std::string& key) override { return s_.Delete(key); }
  std::vector<StoredFile> ListFiles(const std::string& key, bool running) override {
    return s_.ListFiles(key, running);
  }
  absl::StatusOr<std::string> ReadFile(const std::string& key, const std::string& name,
                                       bool running, uint64_t offset, uint64_t max_bytes,
                                       std::string buffer) override {
    return s_.ReadFile(key, name, running, offset, max_bytes, std::move(buffer));
  }

 private:
  ResultStore& s_;
};

// Commits `bytes` for queued job `id` the way the VDB writer leaves a
// result: written, and its digest remembered (RememberFileSha256).
void SucceedAsTheWriterDoes(JobStore& jobs, ResultStore& results, const std::string& id,
                            const std::string& bytes) {
  auto claimed = jobs.ClaimNext("w", kT0 + 1, 1000);
  ASSERT_TRUE(claimed.ok() && *claimed && (*claimed)->id == id);
  const std::filesystem::path scratch = results.ScratchPath(id);
  const int fd = ::open(scratch.c_str(), O_RDWR | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  ASSERT_GE(fd, 0);
  ASSERT_EQ(::write(fd, bytes.data(), bytes.size()), ssize_t(bytes.size()));
  RememberFileSha256(fd, Sha256Hex(bytes));
  ::close(fd);
  auto stored = results.Commit(id, scratch);
  ASSERT_TRUE(stored.ok()) << stored.status();
  EXPECT_EQ(stored->sha256, Sha256Hex(bytes));
  Completion c;
  c.result_key = stored->key;
  c.result_size = stored->size;
  c.result_sha256 = stored->sha256;
  ASSERT_TRUE(jobs.Complete(id, "w", c, kT0 + 1).ok());
}

TEST_F(ResultExportTest, AResultThisProcessWroteIsCopiedWithoutReadingItBack) {
  std::string bytes(5 * (1 << 20) + 77, '\0');
  for (size_t i = 0; i < bytes.size(); ++i) bytes[i] = char(i * 2246822519u >> 11);
  Create("j1");
  SucceedAsTheWriterDoes(*store_, *results_, "j1", bytes);
  CountingStore counting(*results_);
  const auto out = dir_ / "out.vdb";
  std::ofstream(out) << "an older render";
  ASSERT_TRUE(ExportResult(*store_, counting, "j1", out).ok());
  EXPECT_EQ(counting.reads, 0);  // the kernel copied it
  EXPECT_TRUE(testing::ReadFileBytes(out) == bytes);
  EXPECT_FALSE(std::filesystem::exists(out.string() + ".part"));
}

TEST_F(ResultExportTest, ARememberedResultChangedSinceIsHashedAndRefused) {
  Create("j1");
  SucceedAsTheWriterDoes(*store_, *results_, "j1", "the committed bytes");
  // One byte flipped after the commit, at a later modification time.
  const auto stored = dir_ / "results" / "j1.vdb";
  std::ofstream(stored, std::ios::binary) << "the committed bytez";
  std::filesystem::last_write_time(
      stored, std::filesystem::last_write_time(stored) + std::chrono::seconds(2));
  CountingStore counting(*results_);
  const auto out = dir_ / "out.vdb";
  const absl::Status st = ExportResult(*store_, counting, "j1", out);
  EXPECT_GT(counting.reads, 0);
  EXPECT_EQ(st.code(), absl::StatusCode::kDataLoss) << st;
  EXPECT_THAT(st.message(), HasSubstr("sha256 mismatch"));
  EXPECT_FALSE(std::filesystem::exists(out));
}

}  // namespace
}  // namespace nimbus::server
