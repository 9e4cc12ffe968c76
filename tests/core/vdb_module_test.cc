// OpenVDB is a module (core/io/vdb_module.h): the programs do not link
// libopenvdb, processes that write no VDB never load it, and a missing
// module is a clear error. (Its own process: the module is looked up once
// per process, and this test points NIMBUS_VDB_MODULE nowhere.)
#include <gtest/gtest.h>
#include <openvdb/openvdb.h>
#include <sys/wait.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>

#include "absl/status/status.h"
#include "core/io/vdb_io.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

struct Outcome {
  int exit_code = -1;
  std::string output;  // stdout and stderr
};

Outcome Shell(const std::string& command) {
  Outcome run;
  FILE* p = popen((command + " 2>&1").c_str(), "r");
  if (p == nullptr) return run;
  char buf[4096];
  for (size_t n; (n = fread(buf, 1, sizeof buf, p)) > 0;) run.output.append(buf, n);
  const int status = pclose(p);
  run.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return run;
}

// The end of a long output (LD_DEBUG writes pages).
std::string Tail(const std::string& s) { return s.substr(s.size() > 4000 ? s.size() - 4000 : 0); }

std::string Bin(const char* name) { return std::string(NIMBUS_BIN_DIR) + "/" + name; }

// OpenVDB's own dependencies, which no other part of Nimbus needs.
constexpr const char* kVdbOnly[] = {"libopenvdb", "liblog4cplus", "libboost_iostreams", "libblosc"};

TEST(VdbModule, ProgramsDoNotLinkOpenVdb) {
  for (const char* name : {"nimbusd", "nimbus"}) {
    const Outcome ldd = Shell("ldd " + Bin(name));
    ASSERT_NE(ldd.output.find("libc.so"), std::string::npos) << ldd.output;
    for (const char* lib : kVdbOnly)
      EXPECT_EQ(ldd.output.find(lib), std::string::npos) << name << " links " << lib << ":\n"
                                                         << ldd.output;
  }
}

TEST(VdbModule, ModuleIsBuiltInLibNimbus) {
  const std::filesystem::path module =
      std::filesystem::path(NIMBUS_BIN_DIR).parent_path() / "lib" / "nimbus" / "libnimbus_vdb.so";
  ASSERT_TRUE(std::filesystem::exists(module)) << module;
  EXPECT_NE(Shell("ldd " + module.string()).output.find("libopenvdb"), std::string::npos);
}

// LD_DEBUG=files lists every object the dynamic linker maps, dlopen included.
std::string LoadedObjects(const std::string& command) {
  return Shell("LD_DEBUG=files " + command).output;
}

TEST(VdbModule, HelpLoadsNoOpenVdb) {
  const std::string loaded = LoadedObjects(Bin("nimbus") + " --help");
  ASSERT_NE(loaded.find("libc.so"), std::string::npos) << loaded.substr(0, 2000);
  EXPECT_EQ(loaded.find("libnimbus_vdb"), std::string::npos);
  EXPECT_EQ(loaded.find("libopenvdb"), std::string::npos);
}

TEST(VdbModule, PictureRenderRunsWithoutTheModule) {
  testing::TempDir dir;
  // The flam3 comparison's picture: about half a second on two threads.
  const std::string spec =
      std::string(NIMBUS_SOURCE_DIR) + "/bench/flam3/sierpinski_2d_image.json";
  const std::string out = (dir.path() / "s.png").string();
  const Outcome run = Shell("NIMBUS_VDB_MODULE=/nonexistent/libnimbus_vdb.so LD_DEBUG=files " +
                        Bin("nimbus") + " --data-dir " + dir.path().string() +
                        " --threads 2 render --no-cache " + spec + " -o " + out);
  ASSERT_EQ(run.exit_code, 0) << Tail(run.output);
  EXPECT_TRUE(std::filesystem::exists(out));
  EXPECT_EQ(run.output.find("libopenvdb"), std::string::npos);
}

// A volume result is written through the module, loaded on demand.
TEST(VdbModule, VolumeRenderLoadsTheModuleOnDemand) {
  testing::TempDir dir;
  const std::string spec = std::string(NIMBUS_SOURCE_DIR) + "/bench/flam3/sierpinski_2d.json";
  const std::string out = (dir.path() / "s.vdb").string();
  const Outcome run = Shell("LD_DEBUG=files " + Bin("nimbus") + " --data-dir " +
                            dir.path().string() + " --threads 2 render --no-cache " + spec +
                            " -o " + out);
  ASSERT_EQ(run.exit_code, 0) << Tail(run.output);
  EXPECT_TRUE(std::filesystem::exists(out));
  EXPECT_NE(run.output.find("libnimbus_vdb.so"), std::string::npos);
  EXPECT_NE(run.output.find("libopenvdb"), std::string::npos);
}

TEST(VdbModule, MissingModuleIsAStatusNamingThePaths) {
  setenv("NIMBUS_VDB_MODULE", "/nonexistent/libnimbus_vdb.so", 1);
  const absl::StatusOr<DenseVolume> read = ReadVdbFile("/nonexistent/x.vdb");
  ASSERT_EQ(read.status().code(), absl::StatusCode::kFailedPrecondition) << read.status();
  const std::string message(read.status().message());
  EXPECT_NE(message.find("libnimbus_vdb.so"), std::string::npos) << message;
  EXPECT_NE(message.find("NIMBUS_VDB_MODULE"), std::string::npos) << message;
  EXPECT_NE(message.find("/nonexistent/libnimbus_vdb.so"), std::string::npos) << message;
  // Every forwarder reports the same, without throwing or exiting, and
  // writes nothing.
  CountGrid counts(Int3{8, 8, 8});
  counts.Add(1, 2, 3, 5);
  counts.Add(6, 2, 3, 1);
  GridFrame frame;
  frame.resolution = {8, 8, 8};
  frame.bounds = {{0, 0, 0}, {1, 1, 1}};
  testing::TempDir dir;
  EXPECT_EQ(WriteDensityVdb(dir.path() / "y.vdb", counts, frame, {}, {}).code(),
            absl::StatusCode::kFailedPrecondition);
  EXPECT_EQ(WriteIntegerCountsVdb(dir.path() / "c.vdb", counts, frame, {}, {}).code(),
            absl::StatusCode::kFailedPrecondition);
  EXPECT_TRUE(std::filesystem::is_empty(dir.path()));
  EXPECT_EQ(DensityVdbBytes(counts, frame, {}, {}).status().code(),
            absl::StatusCode::kFailedPrecondition);
}

// The downsampling factor's support count (coarse voxels and leaves) no
// longer builds an OpenVDB MaskGrid: OpenVDB's count is the oracle.
GridSupport OracleSupport(const CountGrid& counts, int f) {
  openvdb::MaskGrid mask;
  auto acc = mask.getAccessor();
  counts.ForEachVoxel(
      [&](Int3 v, uint32_t) { acc.setValueOn(openvdb::Coord(v.x / f, v.y / f, v.z / f)); });
  return {mask.activeVoxelCount(), mask.tree().leafCount()};
}

TEST(VdbModule, DownsampleFactorMatchesOpenVdbMaskCounts) {
  CountGrid counts(Int3{150, 120, 90});
  std::mt19937 rng(7);
  for (int i = 0; i < 4000; ++i)  // scattered voxels, plus a dense block
    counts.Add(int(rng() % 150), int(rng() % 120), int(rng() % 90), 1 + rng() % 5);
  for (int x = 40; x < 70; ++x)
    for (int y = 10; y < 33; ++y)
      for (int z = 60; z < 90; ++z) counts.Add(x, y, z, 2);
  const int largest = 150;
  std::vector<GridSupport> oracle(largest + 1);
  for (int g = 1; g <= largest; ++g) oracle[g] = OracleSupport(counts, g);
  for (int f : {2, 3, 5, 8, 13}) {
    DensityOptions o;
    o.conventions.max_voxels = int64_t(oracle[f].voxels);
    int want = 2;
    while (oracle[want].voxels > oracle[f].voxels) ++want;
    EXPECT_EQ(OutputDownsampleFactor(counts, o), want) << "max_voxels, f=" << f;
    // The file-size limit counts leaves too.
    DensityOptions b;
    b.color = true;
    b.conventions.target_file_bytes = int64_t(EstimatedFileBytes(oracle[f], b));
    want = 2;
    while (EstimatedFileBytes(oracle[want], b) > EstimatedFileBytes(oracle[f], b)) ++want;
    EXPECT_EQ(OutputDownsampleFactor(counts, b), want) << "target_file_bytes, f=" << f;
  }
}

}  // namespace
}  // namespace nimbus
