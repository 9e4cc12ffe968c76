// The digest memo may only answer for a file exactly as it was written:
// renamed is the same file, rewritten or grown is not.
#include "core/base/file_digests.h"

#include <fcntl.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <string>

#include "core/base/sha256.h"
#include "core/io/vdb_file.h"
#include "core/io/vdb_module.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

// Writes `bytes` to `path` and remembers their digest, as a writer does.
void WriteAndRemember(const std::filesystem::path& path, const std::string& bytes) {
  const int fd = ::open(path.c_str(), O_RDWR | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  ASSERT_GE(fd, 0);
  ASSERT_EQ(::write(fd, bytes.data(), bytes.size()), ssize_t(bytes.size()));
  RememberFileSha256(fd, Sha256Hex(bytes));
  ::close(fd);
}

TEST(FileDigests, RecallsARenamedFileAndNothingElse) {
  const testing::TempDir tmp;
  WriteAndRemember(tmp / "a.partial", "first contents");
  std::filesystem::rename(tmp / "a.partial", tmp / "a");
  EXPECT_EQ(RecallFileSha256(tmp / "a"), Sha256Hex("first contents"));
  // A file never remembered, a missing one and a folder: nothing.
  const std::string other = "not written by a writer";
  FILE* f = std::fopen((tmp / "b").c_str(), "wb");
  ASSERT_NE(f, nullptr);
  std::fwrite(other.data(), 1, other.size(), f);
  std::fclose(f);
  EXPECT_EQ(RecallFileSha256(tmp / "b"), std::nullopt);
  EXPECT_EQ(RecallFileSha256(tmp / "missing"), std::nullopt);
  EXPECT_EQ(RecallFileSha256(tmp.path()), std::nullopt);
}

TEST(FileDigests, ForgetsAFileChangedSince) {
  const testing::TempDir tmp;
  const std::filesystem::path p = tmp / "c";
  WriteAndRemember(p, "0123456789");
  ASSERT_TRUE(RecallFileSha256(p).has_value());
  // Grown: another size. (Touching mtime alone is what a rewrite of the
  // same size shows; set it explicitly, since two writes may share a tick.)
  {
    FILE* f = std::fopen(p.c_str(), "ab");
    ASSERT_NE(f, nullptr);
    std::fputs("!", f);
    std::fclose(f);
  }
  EXPECT_EQ(RecallFileSha256(p), std::nullopt);
  WriteAndRemember(p, "abcdefghij");
  ASSERT_EQ(RecallFileSha256(p), Sha256Hex("abcdefghij"));
  std::filesystem::last_write_time(p,
                                   std::filesystem::last_write_time(p) + std::chrono::seconds(1));
  EXPECT_EQ(RecallFileSha256(p), std::nullopt);
}

// The writer lives in the OpenVDB module, which has a core/base of its own:
// once loaded, it remembers into this program's memo.
TEST(FileDigests, TheVdbWriterRemembersWhatItWrote) {
  ASSERT_TRUE(LoadVdbModule().ok());
  const testing::TempDir tmp;
  const std::filesystem::path p = tmp / "x.vdb";
  // A minimal archive: the header the UUID stamp looks for, then a body.
  std::string head;
  const int64_t magic = vdb_internal::kVdbMagic;
  head.append(reinterpret_cast<const char*>(&magic), sizeof(magic));
  head.append(13, '\1');
  head += "00000000-0000-0000-0000-000000000000";
  head.append(100000, 'v');
  ASSERT_TRUE(vdb_internal::WriteArchiveAtomically(p, [&](std::ostream& os) {
                os.write(head.data(), std::streamsize(head.size()));
              }).ok());
  // The remembered digest is the stamped file's, byte for byte.
  const auto on_disk = Sha256File(p);
  ASSERT_TRUE(on_disk.ok());
  EXPECT_EQ(RecallFileSha256(p), *on_disk);
  EXPECT_NE(testing::ReadFileBytes(p).substr(21, 36), head.substr(21, 36));  // stamped
}

}  // namespace
}  // namespace nimbus
