#include "core/io/vdb_io.h"

#include <gtest/gtest.h>

#include <cmath>
#include <fstream>

#include "core/base/sha256.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

GridFrame Frame() {
  GridFrame f;
  f.resolution = {40, 33, 70};  // not multiples of the tile size
  f.bounds = {{-1, 0, 2}, {1, 3, 9}};
  return f;
}

TEST(VdbIo, RoundTripThroughAFile) {
  testing::TempDir dir;
  const GridFrame frame = Frame();
  CountGrid counts(frame.resolution);
  counts.Add(0, 0, 0, 5);
  counts.Add(39, 32, 69, 10);
  counts.Add(17, 8, 33, 1);
  const Metadata meta = {{"nimbus_seed", int64_t{42}},
                         {"nimbus_spec_hash", std::string("abc")},
                         {"nimbus_version", std::string(NIMBUS_VERSION)}};
  const auto path = dir / "out.vdb";
  ASSERT_TRUE(WriteDensityVdb(path, counts, frame, {}, meta).ok());
  ASSERT_FALSE(std::filesystem::exists(dir / "out.vdb.partial"));

  auto vol = ReadVdbFile(path);
  ASSERT_TRUE(vol.ok()) << vol.status();
  EXPECT_EQ(vol->grid_class, "fog volume");
  EXPECT_EQ(vol->frame.resolution, frame.resolution);
  EXPECT_EQ(vol->frame.bounds.min, frame.bounds.min);
  EXPECT_EQ(vol->frame.bounds.max, frame.bounds.max);
  EXPECT_FLOAT_EQ(vol->At(0, 0, 0), 0.5f);
  EXPECT_FLOAT_EQ(vol->At(39, 32, 69), 1.0f);
  EXPECT_FLOAT_EQ(vol->At(17, 8, 33), 0.1f);
  EXPECT_FLOAT_EQ(vol->At(1, 1, 1), 0.0f);
  // The transform puts voxel centres inside the spec's bounds.
  const Vec3 h = frame.VoxelSize();
  EXPECT_NEAR(vol->origin_center.x, -1 + h.x / 2, 1e-9);
  EXPECT_NEAR(vol->origin_center.y, 0 + h.y / 2, 1e-9);
  EXPECT_NEAR(vol->origin_center.z, 2 + h.z / 2, 1e-9);
  EXPECT_NEAR(vol->voxel_size.z, h.z, 1e-12);
  ASSERT_NE(vol->Find("nimbus_seed"), nullptr);
  EXPECT_EQ(std::get<int64_t>(*vol->Find("nimbus_seed")), 42);
  EXPECT_EQ(std::get<std::string>(*vol->Find("nimbus_spec_hash")), "abc");
  EXPECT_EQ(std::get<int64_t>(*vol->Find("nimbus_max_count")), 10);
}

TEST(VdbIo, DensityMappings) {
  const GridFrame frame = Frame();
  CountGrid counts(frame.resolution);
  counts.Add(1, 1, 1, 100);
  counts.Add(2, 2, 2, 25);
  DensityOptions o;
  o.mapping = DensityMapping::kSqrt;
  auto bytes = DensityVdbBytes(counts, frame, o, {});
  ASSERT_TRUE(bytes.ok());
  auto vol = ReadVdbBytes(*bytes);
  ASSERT_TRUE(vol.ok()) << vol.status();
  EXPECT_FLOAT_EQ(vol->At(2, 2, 2), 0.5f);
  o.mapping = DensityMapping::kLog;
  vol = ReadVdbBytes(*DensityVdbBytes(counts, frame, o, {}));
  EXPECT_NEAR(vol->At(2, 2, 2), std::log1p(25.0) / std::log1p(100.0), 1e-6);
}

TEST(VdbIo, DownsampleKeepsTotals) {
  CountGrid a({100, 100, 100}), b({100, 100, 100});
  a.Add(99, 99, 99, 3);
  b.Add(99, 98, 97, 4);
  b.Add(0, 0, 0, 1);
  const int f = DownsampleFactor({100, 100, 100}, 32);
  EXPECT_EQ(f, 4);
  const CountGrid c = DownsampleCounts({&a, &b}, f);
  EXPECT_EQ(c.resolution(), (Int3{25, 25, 25}));
  EXPECT_EQ(c.Get(24, 24, 24), 7u);
  EXPECT_EQ(c.Total(), 8u);
}

TEST(VdbIo, ReadingGarbageIsAnError) {
  testing::TempDir dir;
  std::ofstream(dir / "bad.vdb") << "not a vdb";
  EXPECT_FALSE(ReadVdbFile(dir / "bad.vdb").ok());
  EXPECT_FALSE(ReadVdbFile(dir / "missing.vdb").ok());
}

TEST(Sha256, KnownDigest) {
  EXPECT_EQ(Sha256Hex("abc"),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
}

}  // namespace
}  // namespace nimbus
