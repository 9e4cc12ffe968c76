// A full disk while writing a .vdb is a clear RESOURCE_EXHAUSTED failure,
// never a short file under the final name: an injected write fault, and a
// real 1 MiB tmpfs when this process may mount one.
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <sys/mount.h>

#include <cerrno>
#include <cstring>
#include <fstream>

#include "core/io/leaf_runs.h"
#include "core/io/vdb_internal.h"
#include "core/io/vdb_io.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

using ::testing::HasSubstr;

GridFrame Frame(int n) {
  GridFrame f;
  f.resolution = {n, n, n};
  f.bounds = {{-1, -1, -1}, {1, 1, 1}};
  return f;
}

// Counts that compress badly, so the file is about as big as the grid.
CountGrid NoisyCounts(const GridFrame& frame) {
  CountGrid counts(frame.resolution);
  uint64_t x = 88172645463325252ull;
  const Int3 r = frame.resolution;
  for (int i = 0; i < r.x; ++i)
    for (int j = 0; j < r.y; ++j)
      for (int k = 0; k < r.z; ++k) {
        x ^= x << 13, x ^= x >> 7, x ^= x << 17;
        counts.Add(i, j, k, uint32_t(x % 100000) + 1);
      }
  return counts;
}

std::vector<std::string> Names(const std::filesystem::path& dir) {
  std::vector<std::string> names;
  for (const auto& e : std::filesystem::directory_iterator(dir))
    names.push_back(e.path().filename().string());
  return names;
}

std::string Slurp(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

class WriteFault : public ::testing::Test {
 protected:
  void TearDown() override { vdb_internal::SetWriteFaultForTesting(-1, 0); }
};

TEST_F(WriteFault, ShortWriteIsResourceExhaustedAndLeavesNothing) {
  testing::TempDir dir;
  const GridFrame frame = Frame(48);
  const CountGrid counts = NoisyCounts(frame);
  vdb_internal::SetWriteFaultForTesting(4096, ENOSPC);
  const absl::Status st = WriteDensityVdb(dir / "out.vdb", counts, frame, {}, {});
  EXPECT_EQ(st.code(), absl::StatusCode::kResourceExhausted) << st;
  EXPECT_THAT(st.message(), HasSubstr("disk full while writing the result"));
  EXPECT_THAT(st.message(), HasSubstr("out.vdb"));
  EXPECT_TRUE(Names(dir.path()).empty()) << "left: " << Names(dir.path())[0];
}

TEST_F(WriteFault, OtherErrorsAreInternalAndNamed) {
  testing::TempDir dir;
  const GridFrame frame = Frame(16);
  vdb_internal::SetWriteFaultForTesting(10, EIO);
  const absl::Status st = WriteDensityVdb(dir / "x.vdb", NoisyCounts(frame), frame, {}, {});
  EXPECT_EQ(st.code(), absl::StatusCode::kInternal) << st;
  EXPECT_THAT(st.message(), HasSubstr(std::strerror(EIO)));
  EXPECT_TRUE(Names(dir.path()).empty());
}

TEST_F(WriteFault, AFailedWriteKeepsThePreviousFile) {
  testing::TempDir dir;
  const GridFrame frame = Frame(16);
  const CountGrid counts = NoisyCounts(frame);
  ASSERT_TRUE(WriteDensityVdb(dir / "out.vdb", counts, frame, {}, {}).ok());
  const std::string before = Slurp(dir / "out.vdb");
  vdb_internal::SetWriteFaultForTesting(100, ENOSPC);
  CountGrid other(frame.resolution);
  other.Add(1, 2, 3, 7);
  EXPECT_FALSE(WriteDensityVdb(dir / "out.vdb", other, frame, {}, {}).ok());
  EXPECT_EQ(Slurp(dir / "out.vdb"), before);
}

TEST_F(WriteFault, CheckedWriterKeepsBytesDeterministicAndReadable) {
  testing::TempDir dir;
  const GridFrame frame = Frame(24);
  const CountGrid counts = NoisyCounts(frame);
  ASSERT_TRUE(WriteDensityVdb(dir / "a.vdb", counts, frame, {}, {}).ok());
  ASSERT_TRUE(WriteDensityVdb(dir / "b.vdb", counts, frame, {}, {}).ok());
  EXPECT_EQ(Slurp(dir / "a.vdb"), Slurp(dir / "b.vdb"));
  auto vol = ReadVdbFile(dir / "a.vdb");
  ASSERT_TRUE(vol.ok()) << vol.status();
  EXPECT_EQ(vol->frame.resolution, frame.resolution);
  EXPECT_GT(vol->At(3, 4, 5), 0.0f);
}

// A real full file system: a 1 MiB tmpfs and a result of several MiB.
TEST(DiskFull, TinyTmpfsGivesResourceExhausted) {
  testing::TempDir dir;
  const std::filesystem::path mnt = dir / "tiny";
  std::filesystem::create_directories(mnt);
  if (::mount("tmpfs", mnt.c_str(), "tmpfs", 0, "size=1m") != 0)
    GTEST_SKIP() << "cannot mount a tmpfs here (" << std::strerror(errno) << ")";
  const GridFrame frame = Frame(96);
  const absl::Status st = WriteDensityVdb(mnt / "big.vdb", NoisyCounts(frame), frame, {}, {});
  const std::vector<std::string> left = Names(mnt);
  ::umount2(mnt.c_str(), MNT_DETACH);
  EXPECT_EQ(st.code(), absl::StatusCode::kResourceExhausted) << st;
  EXPECT_THAT(st.message(), HasSubstr("disk full while writing the result"));
  EXPECT_TRUE(left.empty()) << "left: " << left[0];
}

// Leaves that spill to a full disk: the same RESOURCE_EXHAUSTED as the
// file's own writes, naming the result and the spill's folder (one of the
// caller's choosing, not the result's own).
TEST(DiskFull, FullSpillDiskGivesResourceExhausted) {
  testing::TempDir dir;
  const std::filesystem::path mnt = dir / "spill";
  std::filesystem::create_directories(mnt);
  if (::mount("tmpfs", mnt.c_str(), "tmpfs", 0, "size=64k") != 0)
    GTEST_SKIP() << "cannot mount a tmpfs here (" << std::strerror(errno) << ")";
  absl::Status st;
  {
    const vdb_internal::SpillScope spill(mnt, 0);
    const GridFrame frame = Frame(48);
    st = WriteDensityVdb(dir / "out.vdb", NoisyCounts(frame), frame, {}, {});
  }
  ::umount2(mnt.c_str(), MNT_DETACH);
  EXPECT_EQ(st.code(), absl::StatusCode::kResourceExhausted) << st;
  EXPECT_THAT(st.message(), HasSubstr("disk full while writing the result"));
  EXPECT_THAT(st.message(), HasSubstr("out.vdb"));
  EXPECT_THAT(st.message(), HasSubstr("leaf spill file: write failed in " + mnt.string()));
  EXPECT_EQ(Names(dir.path()), std::vector<std::string>{"spill"});
}

}  // namespace
}  // namespace nimbus
