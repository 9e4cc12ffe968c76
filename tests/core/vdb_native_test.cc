// The native VDB writer (core/io/vdb_native.h) piece by piece against
// OpenVDB: half conversion, leaf buffers (LeafNode::writeBuffers), linear
// transforms (Transform::write, voxelSize), and whole result files against
// the OpenVDB module's writers on results with many shapes.
#include "core/io/vdb_native.h"

#include <gtest/gtest.h>
#include <openvdb/io/Compression.h>
#include <openvdb/openvdb.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <fstream>
#include <random>
#include <sstream>
#include <string>

#include "core/io/result_values.h"
#include "core/io/vdb_impl.h"
#include "core/io/vdb_internal.h"
#include "core/io/vdb_io.h"
#include "core/io/vdb_native_result.h"
#include "core/io/vdb_stream.h"
#include "tests/support/count_scatter.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

using vdb_native::LeafMask;
using vdb_native::ValueKind;

std::string Slurp(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

uint16_t OpenVdbHalf(float f) { return openvdb::math::half(f).bits(); }

TEST(VdbNative, HalfConversionMatchesOpenVdb) {
  // Every exponent and sign with strided mantissas, plus the edges.
  uint64_t checked = 0;
  for (uint64_t u = 0; u < (uint64_t{1} << 32); u += 4093) {
    float f;
    const uint32_t bits = uint32_t(u);
    std::memcpy(&f, &bits, sizeof(f));
    ASSERT_EQ(vdb_native::FloatToHalf(f), OpenVdbHalf(f)) << std::hex << bits;
    ++checked;
  }
  for (uint32_t bits : {0x00000000u, 0x80000000u, 0x33000000u, 0x33000001u, 0x387fffffu,
                        0x38800000u, 0x477fefffu, 0x477ff000u, 0x7f800000u, 0xff800000u,
                        0x7f800001u, 0x7fc00000u, 0x7f802000u, 0x3f800000u, 0x3c7fe000u}) {
    float f;
    std::memcpy(&f, &bits, sizeof(f));
    EXPECT_EQ(vdb_native::FloatToHalf(f), OpenVdbHalf(f)) << std::hex << bits;
  }
  // Ties around every subnormal and normal step.
  std::mt19937 rng(1);
  for (int i = 0; i < 2000000; ++i) {
    const float f = std::ldexp(float(rng() % 4096) + 0.5f, -int(rng() % 40)) * 1e-3f;
    ASSERT_EQ(vdb_native::FloatToHalf(f), OpenVdbHalf(f)) << f;
  }
  EXPECT_GT(checked, 1000000u);
}

// OpenVDB's encoding of a leaf with `mask` and `values` (inactive ones 0).
template <typename LeafT>
std::string OpenVdbLeaf(const LeafMask& mask, const typename LeafT::ValueType* values, bool half) {
  LeafT leaf(openvdb::Coord(0), typename LeafT::ValueType(0));
  for (int i = 0; i < 512; ++i)
    if ((mask[size_t(i >> 6)] >> (i & 63)) & 1) leaf.setValueOn(openvdb::Index(i), values[i]);
  std::ostringstream os(std::ios_base::binary);
  openvdb::io::setDataCompression(os, vdb_internal::kArchiveCompression);
  const typename LeafT::ValueType zero(0);
  openvdb::io::setGridBackgroundValuePtr(os, &zero);
  leaf.writeBuffers(os, half);
  return os.str();
}

// Random masks (empty, full, sparse, dense) and values for one kind.
template <typename LeafT, typename Make>
void CheckLeaves(ValueKind kind, const Make& make) {
  using V = typename LeafT::ValueType;
  std::mt19937_64 rng(42);
  for (int trial = 0; trial < 300; ++trial) {
    LeafMask mask{};
    const int density = trial % 5;  // 0: empty ... 4: full
    for (int i = 0; i < 512; ++i)
      if (density == 4 || (density > 0 && int(rng() % 4) < density))
        mask[size_t(i >> 6)] |= uint64_t{1} << (i & 63);
    std::vector<V> values(512, V(0)), packed;
    for (int i = 0; i < 512; ++i)
      if ((mask[size_t(i >> 6)] >> (i & 63)) & 1) packed.push_back(values[size_t(i)] = make(rng));
    for (bool half : {false, true}) {
      const std::string ref = OpenVdbLeaf<LeafT>(mask, values.data(), half);
      std::string mine;
      const int64_t size =
          vdb_native::EncodeLeaf(kind, half, mask, packed.data(), packed.size(), mine);
      ASSERT_EQ(mine, ref) << "trial " << trial << " half " << half;
      EXPECT_EQ(size, vdb_internal::DelayedLoadSize(ref, sizeof(V)));
    }
  }
}

TEST(VdbNative, LeafBuffersMatchOpenVdb) {
  vdb_internal::InitOpenVdb();
  // Smooth values compress, noise does not: both Blosc outcomes.
  CheckLeaves<openvdb::FloatTree::LeafNodeType>(ValueKind::kFloat, [](auto& rng) {
    return rng() % 3 ? float(rng() % 7) * 0.125f : float(double(rng()) * 1e-19);
  });
  CheckLeaves<openvdb::Vec3STree::LeafNodeType>(ValueKind::kVec3f, [](auto& rng) {
    return openvdb::Vec3s(float(rng() % 5), float(double(rng()) * 1e-19), 0.25f);
  });
  CheckLeaves<openvdb::Int64Tree::LeafNodeType>(ValueKind::kInt64, [](auto& rng) {
    return rng() % 2 ? int64_t(rng() % 9) : int64_t(rng());
  });
}

// Transform::write and voxelSize of createLinearTransform(m).
void CheckTransform(const openvdb::math::Mat4d& m) {
  const auto ref = openvdb::math::Transform::createLinearTransform(m);
  std::ostringstream os(std::ios_base::binary);
  ref->write(os);
  vdb_native::LinearTransform mine{};
  for (int i = 0; i < 4; ++i)
    for (int j = 0; j < 4; ++j) mine.m[i][j] = m(i, j);
  ASSERT_EQ(mine.Bytes(), os.str()) << m << " " << ref->mapType();
  const openvdb::Vec3d h = ref->voxelSize();
  const std::array<double, 3> hv = mine.VoxelSize();
  EXPECT_EQ(hv[0], h.x()) << m;
  EXPECT_EQ(hv[1], h.y()) << m;
  EXPECT_EQ(hv[2], h.z()) << m;
}

TEST(VdbNative, LinearTransformsMatchOpenVdb) {
  vdb_internal::InitOpenVdb();
  std::mt19937 rng(3);
  auto pick = [&](std::initializer_list<double> v) { return *(v.begin() + rng() % v.size()); };
  for (int trial = 0; trial < 2000; ++trial) {
    GridFrame frame;
    const int n = int(pick({1, 7, 64, 256, 1024}));
    frame.resolution = {n, int(pick({1, 3, 64, 256, 1024})), n};
    const double lo = pick({-1, -0.5, 0, -5.4, -2, -0.1, -1.0 / 512});
    const double ext = pick({1, 2, 1.2, 10.8, 4, 3.0});
    frame.bounds = {{lo, lo * 0.5, lo}, {lo + ext, lo * 0.5 + ext * pick({1, 0.5}), lo + ext}};
    for (UpAxis up : {UpAxis::kY, UpAxis::kZ})
      CheckTransform(vdb_internal::FrameTransform(frame, up)->baseMap()->getAffineMap()->getMat4());
  }
  // Translation-free and near-uniform scales too.
  openvdb::math::Mat4d m = openvdb::math::Mat4d::identity();
  m.setToScale(openvdb::Vec3d(0.5, 0.5, 0.5));
  CheckTransform(m);
  m.setToScale(openvdb::Vec3d(0.5, 0.5 + 1e-16, 0.25));
  CheckTransform(m);
  m.setTranslation(openvdb::Vec3d(1e-16, 0, 0));
  CheckTransform(m);
}

// The density mappings with their table of small counts give the floats
// of the formulas, below the table's end, at it and past it.
TEST(VdbNative, NormaliserTableGivesTheMappingsFloats) {
  for (DensityMapping m : {DensityMapping::kLinear, DensityMapping::kSqrt, DensityMapping::kLog,
                           DensityMapping::kGamma}) {
    for (uint32_t max : {1u, 7u, 4096u, 100000u}) {
      DensityOptions o;
      o.mapping = m;
      o.gamma = 2.2;
      const Normaliser norm(o, max);
      const double mx = std::max<double>(1, max);
      auto want = [&](uint32_t c) {
        switch (m) {
          case DensityMapping::kLinear:
            return float(c * (1.0 / mx));
          case DensityMapping::kSqrt:
            return float(std::sqrt(c * (1.0 / mx)));
          case DensityMapping::kLog:
            return float(std::log1p(double(c)) * (1.0 / std::log1p(mx)));
          case DensityMapping::kGamma:
            return float(std::pow(c * (1.0 / mx), 1.0 / 2.2));
        }
        return 0.f;
      };
      for (uint32_t c = 0; c <= std::min<uint32_t>(max, 5000); ++c)
        ASSERT_EQ(norm(c), want(c)) << MappingName(m) << " max " << max << " count " << c;
      ASSERT_EQ(norm(max), want(max)) << MappingName(m) << " max " << max;
    }
  }
}

struct Shape {
  Int3 resolution;
  int samples;
  bool color, address, half;
  RawCounts raw;
  UpAxis up;
};

class VdbNativeResults : public ::testing::TestWithParam<Shape> {};

// The native file against the module's streamed writer and OpenVDB's own
// writer of built grids, for the result and its integer counts.
TEST_P(VdbNativeResults, MatchTheModule) {
  const Shape& k = GetParam();
  testing::TempDir dir;
  GridFrame frame;
  frame.resolution = k.resolution;
  frame.bounds = {{-1.5, 0, -0.25}, {2.5, 3, 0.75}};
  const CountGrid counts =
      testing::ScatterColorCounts(k.resolution, k.samples, uint32_t(k.resolution.x));
  DensityOptions o;
  o.mapping = DensityMapping::kSqrt;
  o.color = k.color;
  o.address_grid = k.address;
  o.raw_counts = k.raw;
  o.conventions.half_float = k.half;
  o.conventions.up_axis = k.up;
  const Metadata meta = {{"nimbus_seed", int64_t{3}}, {"nimbus_scale", 0.5}};
  ASSERT_TRUE(vdb_native::CanWriteResult(counts, o));
  const auto n = dir.path() / "n.vdb", m = dir.path() / "m.vdb", b = dir.path() / "b.vdb";
  ASSERT_TRUE(vdb_native::WriteDensityVdb(n, counts, frame, o, meta, {}).ok());
  ASSERT_TRUE(vdb_impl::WriteDensityVdb(m, counts, frame, o, meta, {}).ok());
  ASSERT_TRUE(vdb_internal::WriteBuiltDensityVdb(b, counts, frame, o, meta).ok());
  const std::string native = Slurp(n);
  EXPECT_EQ(native, Slurp(m));
  EXPECT_EQ(native, Slurp(b));
  ASSERT_TRUE(vdb_native::WriteIntegerCountsVdb(n, counts, frame, o, meta).ok());
  ASSERT_TRUE(vdb_impl::WriteIntegerCountsVdb(m, counts, frame, o, meta).ok());
  EXPECT_EQ(Slurp(n), Slurp(m));
}

INSTANTIATE_TEST_SUITE_P(
    Shapes, VdbNativeResults,
    ::testing::Values(
        Shape{{64, 64, 64}, 30000, false, false, false, RawCounts::kNone, UpAxis::kY},
        Shape{{256, 256, 1}, 50000, true, false, true, RawCounts::kFloat, UpAxis::kY},
        Shape{{33, 300, 17}, 20000, true, true, false, RawCounts::kInteger, UpAxis::kZ},
        // Several root children (past 4096 voxels) and half floats.
        Shape{{4500, 16, 9}, 30000, true, true, true, RawCounts::kFloat, UpAxis::kZ},
        Shape{{9000, 3, 1}, 5000, false, false, false, RawCounts::kInteger, UpAxis::kY},
        // Nothing counted: an empty tree, its invalid bounding box.
        Shape{{16, 16, 16}, 0, true, true, false, RawCounts::kFloat, UpAxis::kY}));

// Grids of several MiB: their leaves leave the encoder in many runs, every
// run spilled (a scope that keeps nothing in memory), and the UUID hashed
// as the file is written front to back is the one read back from it.
TEST(VdbNative, SpilledMultiRunGridsMatchTheModule) {
  testing::TempDir dir;
  GridFrame frame;
  frame.resolution = {96, 96, 96};
  frame.bounds = {{-1, -1, -1}, {1, 1, 1}};
  const CountGrid counts = testing::ScatterColorCounts(frame.resolution, 1'500'000, 7);
  DensityOptions o;
  o.color = true;
  const auto n = dir.path() / "n.vdb", m = dir.path() / "m.vdb";
  {
    vdb_internal::SpillScope keep_nothing(dir.path(), 0);
    ASSERT_TRUE(vdb_native::WriteDensityVdb(n, counts, frame, o, {}, {}).ok());
  }
  ASSERT_TRUE(vdb_impl::WriteDensityVdb(m, counts, frame, o, {}, {}).ok());
  const std::string native = Slurp(n);
  EXPECT_GT(native.size(), size_t{8} << 20);
  EXPECT_EQ(native, Slurp(m));
  ASSERT_TRUE(vdb_internal::StampContentUuid(n).ok());
  EXPECT_EQ(Slurp(n), native);
}

TEST(VdbNative, DownsampledResultsAreLeftToTheModule) {
  const CountGrid counts = testing::ScatterColorCounts({64, 64, 64}, 30000, 1);
  DensityOptions o;
  EXPECT_TRUE(vdb_native::CanWriteResult(counts, o));
  o.conventions.max_voxels = 1000;
  EXPECT_FALSE(vdb_native::CanWriteResult(counts, o));
  const std::vector<Vec3Field> outside = {{"v", {{{-1, 0, 0}, {1, 0, 0}}}}};
  EXPECT_FALSE(vdb_native::CanWriteResult(counts, DensityOptions{}, outside));
}

}  // namespace
}  // namespace nimbus
