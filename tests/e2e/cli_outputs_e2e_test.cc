// `nimbus render -o` through the real CLI and its embedded server: every
// file it writes has its format's extension, read back through that
// format's own library.
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <cstdlib>
#include <fstream>

#include "core/io/image_io.h"
#include "core/io/vdb_io.h"
#include "proto/spec_io.h"
#include "tests/support/server_fixture.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

// arcs_image (a volume and a picture beside it), small enough for a test.
v1::JobSpec SmallArcs() {
  v1::JobSpec spec = testing::LoadExample("arcs_image.json");
  spec.mutable_grid()->clear_resolution();
  for (int r : {32, 32, 4}) spec.mutable_grid()->add_resolution(r);
  spec.mutable_chaos_game()->set_iterations(2'000'000);
  spec.mutable_image()->set_width(120);
  spec.mutable_image()->set_supersample(1);
  return spec;
}

// Runs `nimbus render` on `spec` with -o `out`; its output (the server's
// log lines with -v among them) goes to `log`.
int Render(const testing::TempDir& dir, const v1::JobSpec& spec, const std::filesystem::path& out,
           const std::filesystem::path& log, const std::string& flags = "") {
  std::ofstream(dir / "spec.json") << spec::SpecToJson(spec);
  const std::string cmd = std::string(NIMBUS_BIN_DIR) + "/nimbus " + flags +
                          " --threads 1 --data-dir " + (dir / "data").string() +
                          " render --no-cache " + (dir / "spec.json").string() + " -o " +
                          out.string() + " >" + log.string() + " 2>&1";
  return WEXITSTATUS(std::system(cmd.c_str()));
}

TEST(CliOutputsE2E, PngOutputOfAVolumeWithAPictureWritesTheVolumeAsVdbBesideIt) {
  testing::TempDir dir;
  ASSERT_EQ(Render(dir, SmallArcs(), dir / "out" / "arcs.png", dir / "log"), 0)
      << testing::ReadFileBytes(dir / "log");
  auto volume = ReadVdbFile(dir / "out" / "arcs.vdb");
  ASSERT_TRUE(volume.ok()) << volume.status();
  EXPECT_EQ(volume->frame.resolution.x, 32);
  EXPECT_EQ(volume->frame.resolution.z, 4);
  auto picture = ReadPngPixels(dir / "out" / "arcs.png");
  ASSERT_TRUE(picture.ok()) << picture.status();
  EXPECT_EQ(picture->width, 120);
  EXPECT_EQ(picture->channels, 3);
  const std::string log = testing::ReadFileBytes(dir / "log");
  EXPECT_NE(log.find("wrote " + (dir / "out" / "arcs.vdb").string() + " ("), std::string::npos)
      << log;
  EXPECT_NE(log.find("wrote " + (dir / "out" / "arcs.png").string() + "\n"), std::string::npos)
      << log;
  EXPECT_EQ(log.find("frames"), std::string::npos) << log;
}

// The embedded server is stopped (its log's last event), not abandoned by
// an exit, after the result is written.
TEST(CliOutputsE2E, RenderStopsItsEmbeddedServer) {
  testing::TempDir dir;
  v1::JobSpec spec = SmallArcs();
  spec.clear_image();
  ASSERT_EQ(Render(dir, spec, dir / "a.vdb", dir / "log", "-v"), 0)
      << testing::ReadFileBytes(dir / "log");
  const std::string log = testing::ReadFileBytes(dir / "log");
  const size_t wrote = log.find("wrote " + (dir / "a.vdb").string());
  ASSERT_NE(wrote, std::string::npos) << log;
  EXPECT_NE(log.find("event=stopped", wrote), std::string::npos) << log;
}

TEST(CliOutputsE2E, VdbOutputOfAPictureOnlyJobIsRefusedBeforeItRuns) {
  testing::TempDir dir;
  v1::JobSpec spec = SmallArcs();
  spec.mutable_image()->set_image_only(true);
  ASSERT_EQ(Render(dir, spec, dir / "p.vdb", dir / "log"), 2);
  const std::string log = testing::ReadFileBytes(dir / "log");
  EXPECT_NE(log.find("-o " + (dir / "p.vdb").string() +
                     ": this job's main result is a PNG "
                     "picture, not a .vdb file; name it " +
                     (dir / "p.png").string()),
            std::string::npos)
      << log;
  EXPECT_FALSE(std::filesystem::exists(dir / "p.vdb"));
  EXPECT_FALSE(std::filesystem::exists(dir / "data"));  // no server was started
}

}  // namespace
}  // namespace nimbus
