// Dense preview files (issue 14): the CLI saves NAME.preview.0001.vdb,
// 0002, … without gaps whatever sequence numbers the server skipped, each
// file naming in its metadata the preview sequence and progress it shows.
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <fstream>
#include <set>

#include "client/preview_files.h"
#include "core/io/metadata_keys.h"
#include "core/io/vdb_io.h"
#include "proto/spec_io.h"
#include "tests/support/nimbusd_process.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

std::vector<std::string> FileNames(const std::filesystem::path& dir) {
  std::set<std::string> names;
  for (const auto& e : std::filesystem::directory_iterator(dir))
    names.insert(e.path().filename().string());
  return {names.begin(), names.end()};
}

TEST(PreviewSaver, NumbersDenselyAndDropsRepeats) {
  testing::TempDir dir;
  client::PreviewSaver saver(dir.path());
  std::vector<std::string> saved;
  for (uint64_t seq : {3, 5, 5, 9, 4, 12}) {
    v1::Preview p;
    p.set_sequence(seq);
    p.set_vdb("bytes " + std::to_string(seq));
    auto path = saver.Save("tree", p);
    ASSERT_TRUE(path.ok()) << path.status();
    if (*path) saved.push_back(std::filesystem::path(**path).filename().string());
  }
  EXPECT_EQ(saved, (std::vector<std::string>{"tree.preview.0001.vdb", "tree.preview.0002.vdb",
                                             "tree.preview.0003.vdb", "tree.preview.0004.vdb"}));
  EXPECT_EQ(saver.saved(), 4u);
  EXPECT_EQ(FileNames(dir.path()), saved);  // no temporary file left behind
  EXPECT_EQ(testing::ReadFileBytes(dir / "tree.preview.0003.vdb"), "bytes 9");
  EXPECT_EQ(client::PreviewFileName("", 12), "nimbus.preview.0012.vdb");
}

TEST(PreviewSaver, UnwritableFolderIsAnError) {
  client::PreviewSaver saver("/nonexistent/folder");
  v1::Preview p;
  p.set_sequence(1);
  EXPECT_FALSE(saver.Save("t", p).ok());
}

int RunCli(const std::string& args) {
  const std::string cmd = std::string(NIMBUS_BIN_DIR) + "/nimbus " + args + " >/dev/null 2>&1";
  return WEXITSTATUS(std::system(cmd.c_str()));
}

TEST(PreviewFilesE2E, CliRenderSavesGaplessPreviewsFromARealServer) {
  testing::TempDir dir;
  testing::NimbusdProcess server(dir / "data", {"--workers", "1", "--log-level", "warn"});
  ASSERT_TRUE(server.Start().ok());
  auto spec = spec::LoadSpecFile(testing::SourcePath("examples/tree.json"));
  ASSERT_TRUE(spec.ok());
  spec->mutable_grid()->clear_resolution();
  for (int r : {16, 128, 120}) spec->mutable_grid()->add_resolution(r);
  // Long enough (seconds) that a loaded machine still sends several previews.
  spec->mutable_chaos_game()->set_iterations(500'000'000);
  spec->mutable_output()->set_up_axis(v1::UP_AXIS_Z);
  std::ofstream(dir / "tree.json") << spec::SpecToJson(*spec);
  ASSERT_EQ(RunCli("--server " + server.target() + " render " + (dir / "tree.json").string() +
                   " -o " + (dir / "tree.vdb").string() + " --previews " +
                   (dir / "previews").string() +
                   " --preview-resolution 32 --preview-interval 0.02"),
            0);
  const std::vector<std::string> names = FileNames(dir / "previews");
  ASSERT_GE(names.size(), 2u);
  int64_t last_sequence = 0, last_done = 0;
  for (size_t i = 0; i < names.size(); ++i) {
    char want[40];
    std::snprintf(want, sizeof want, "tree.preview.%04zu.vdb", i + 1);
    ASSERT_EQ(names[i], want);
    auto v = ReadVdbFile(dir / "previews" / names[i]);
    ASSERT_TRUE(v.ok()) << v.status();
    const MetaValue* seq = v->Find(meta_key::kPreviewSequence);
    const MetaValue* done = v->Find(meta_key::kPreviewDone);
    ASSERT_TRUE(seq && done);
    EXPECT_GT(std::get<int64_t>(*seq), last_sequence);
    EXPECT_GE(std::get<int64_t>(*done), last_done);
    last_sequence = std::get<int64_t>(*seq);
    last_done = std::get<int64_t>(*done);
    // Previews follow the job's conventions too.
    const MetaValue* up = v->Find(meta_key::kUpAxis);
    ASSERT_TRUE(up);
    EXPECT_EQ(std::get<std::string>(*up), "Z");
  }
  std::cerr << names.size() << " preview files for sequences up to " << last_sequence << "\n";
}

}  // namespace
}  // namespace nimbus
