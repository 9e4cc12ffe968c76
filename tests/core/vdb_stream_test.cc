// The streamed VDB writer (core/io/vdb_stream.h) must write exactly the
// bytes OpenVDB's own writer writes for the same grids: for in-memory grids
// of every type and mask-compression case, and for results written from
// counts (every optional grid, conventions, folded thin grids, fog volumes).
#include "core/io/vdb_stream.h"

#include <gtest/gtest.h>
#include <openvdb/openvdb.h>

#include <fstream>
#include <random>
#include <sstream>
#include <string>

#include "core/io/vdb_internal.h"
#include "core/io/vdb_io.h"
#include "tests/support/count_scatter.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

std::string Slurp(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

// A producer that encodes a built grid's own leaves.
template <typename GridT>
vdb_internal::GridProducer Copying(typename GridT::Ptr grid) {
  using LeafT = typename GridT::TreeType::LeafNodeType;
  return {grid->getName(), [grid] {
            return vdb_internal::EncodeLeaves<GridT>(
                grid,
                [](const LeafT& topo, LeafT& leaf) {
                  for (openvdb::Index i = 0; i < LeafT::SIZE; ++i)
                    leaf.setValueOnly(i, topo.getValue(i));
                },
                [](const LeafT*, size_t) {});
          }};
}

// Random sparse grids whose inactive voxels hold 0, 1 or 2 values besides
// the background, and a half-float one: every LeafNode encoding.
TEST(VdbStream, MatchesOpenVdbForBuiltGrids) {
  vdb_internal::InitOpenVdb();
  testing::TempDir dir;
  std::mt19937 rng(7);
  std::uniform_int_distribution<int> pos(0, 60);
  auto make = [&](const std::string& name, float bg, int kinds, bool half) {
    auto g = openvdb::FloatGrid::create(bg);
    g->setName(name);
    auto acc = g->getAccessor();
    for (int n = 0; n < 3000; ++n) {
      const openvdb::Coord c(pos(rng), pos(rng), pos(rng));
      if (n % 3 == 0 && kinds > 0)
        acc.setValueOff(c, n % 2 || kinds == 1 ? -bg : 0.5f);  // inactive, not background
      else
        acc.setValueOn(c, float(n) * 0.25f);
    }
    g->setSaveFloatAsHalf(half);
    return g;
  };
  auto v = openvdb::Vec3SGrid::create();
  v->setName("v");
  auto i64 = openvdb::Int64Grid::create();
  i64->setName("i");
  for (int n = 0; n < 2000; ++n) {
    const openvdb::Coord c(pos(rng), pos(rng), -pos(rng));
    v->tree().setValueOn(c, openvdb::Vec3s(float(n), 1, -2));
    i64->tree().setValueOn(c, int64_t(n) << 33);
  }
  auto empty = openvdb::FloatGrid::create();
  empty->setName("empty");
  auto a = make("a", 0.f, 0, false), b = make("b", 3.f, 1, false), c = make("a", 3.f, 2, true);
  const openvdb::GridPtrVec grids{a, b, c, v, i64, empty};
  ASSERT_TRUE(vdb_internal::WriteGridsAtomically(dir.path() / "ref.vdb", grids).ok());
  const std::vector<vdb_internal::GridProducer> producers{
      Copying<openvdb::FloatGrid>(a),     Copying<openvdb::FloatGrid>(b),
      Copying<openvdb::FloatGrid>(c),     Copying<openvdb::Vec3SGrid>(v),
      Copying<openvdb::Int64Grid>(i64), Copying<openvdb::FloatGrid>(empty)};
  ASSERT_TRUE(vdb_internal::WriteStreamedAtomically(dir.path() / "s.vdb", producers).ok());
  EXPECT_EQ(Slurp(dir.path() / "s.vdb"), Slurp(dir.path() / "ref.vdb"));
}

// Grids whose encoded leaves spill to a file, wholly or past a few runs,
// write the same bytes, leave nothing in the spill directory, and a spill
// directory that cannot take the file is an error that names it.
TEST(VdbStream, SpilledLeavesWriteTheSameBytes) {
  vdb_internal::InitOpenVdb();
  testing::TempDir dir;
  auto g = openvdb::FloatGrid::create(0.f);
  g->setName("density");
  auto acc = g->getAccessor();
  std::mt19937 rng(11);
  std::uniform_int_distribution<int> pos(0, 200);
  for (int n = 0; n < 40000; ++n) acc.setValueOn({pos(rng), pos(rng), pos(rng)}, float(n % 97));
  ASSERT_GT(g->tree().leafCount(), 512u);  // several runs of 256 leaves
  ASSERT_TRUE(vdb_internal::WriteGridsAtomically(dir.path() / "ref.vdb", {g}).ok());
  const std::string ref = Slurp(dir.path() / "ref.vdb");
  const std::filesystem::path spill_dir = dir.path() / "spill";
  std::filesystem::create_directories(spill_dir);
  for (uint64_t keep : {uint64_t{0}, uint64_t{100000}, uint64_t{1} << 30}) {
    const vdb_internal::SpillScope spill(spill_dir, keep);
    const std::filesystem::path out = dir.path() / ("s" + std::to_string(keep) + ".vdb");
    ASSERT_TRUE(vdb_internal::WriteStreamedAtomically(out, {Copying<openvdb::FloatGrid>(g)}).ok());
    EXPECT_EQ(Slurp(out), ref) << "keep " << keep;
    EXPECT_TRUE(std::filesystem::is_empty(spill_dir)) << "keep " << keep;
  }
  vdb_internal::EncodedGrid spilled = [&] {
    const vdb_internal::SpillScope spill(spill_dir, 0);
    return Copying<openvdb::FloatGrid>(g).make();
  }();
  EXPECT_TRUE(spilled.buffers.spilled());
  const vdb_internal::SpillScope missing(dir.path() / "no" / "such", 0);
  const absl::Status st =
      vdb_internal::WriteStreamedAtomically(dir.path() / "x.vdb", {Copying<openvdb::FloatGrid>(g)});
  EXPECT_FALSE(st.ok());
  EXPECT_NE(st.message().find("no/such"), std::string::npos) << st;
  EXPECT_FALSE(std::filesystem::exists(dir.path() / "x.vdb"));
  EXPECT_FALSE(std::filesystem::exists(dir.path() / "x.vdb.partial"));
}

struct Case {
  Int3 resolution;
  DensityMapping mapping;
  bool half;
  UpAxis up;
  bool modulate;
};

class VdbStreamResults : public ::testing::TestWithParam<Case> {};

TEST_P(VdbStreamResults, MatchWholeGridWriter) {
  const Case& k = GetParam();
  testing::TempDir dir;
  GridFrame frame;
  frame.resolution = k.resolution;
  frame.bounds = {{-1, -2, -0.5}, {1, 2, 0.5}};
  const CountGrid counts = testing::ScatterColorCounts(k.resolution, 40000, 3);
  DensityOptions o;
  o.mapping = k.mapping;
  o.color = o.address_grid = true;
  o.raw_counts = RawCounts::kInteger;
  o.conventions.half_float = k.half;
  o.conventions.up_axis = k.up;
  if (k.modulate) o.modulation = [](const Vec3& p) { return 0.5 + p.x - 0.25 * p.y; };
  const Metadata meta = {{"nimbus_seed", int64_t{9}}, {"nimbus_note", std::string("x")}};
  const std::vector<Vec3Field> fields = {{"v", {{{1, 2, 0}, {1, 2, 3}}, {{9, 9, 0}, {0, 1, 0}}}}};
  ASSERT_TRUE(WriteDensityVdb(dir.path() / "s.vdb", counts, frame, o, meta, fields).ok());
  ASSERT_TRUE(
      vdb_internal::WriteBuiltDensityVdb(dir.path() / "w.vdb", counts, frame, o, meta, fields)
          .ok());
  EXPECT_EQ(Slurp(dir.path() / "s.vdb"), Slurp(dir.path() / "w.vdb"));
  ASSERT_TRUE(WriteIntegerCountsVdb(dir.path() / "si.vdb", counts, frame, o, meta).ok());
  ASSERT_TRUE(
      vdb_internal::WriteBuiltIntegerCountsVdb(dir.path() / "wi.vdb", counts, frame, o, meta)
          .ok());
  EXPECT_EQ(Slurp(dir.path() / "si.vdb"), Slurp(dir.path() / "wi.vdb"));
}

INSTANTIATE_TEST_SUITE_P(
    Cases, VdbStreamResults,
    ::testing::Values(Case{{100, 90, 1}, DensityMapping::kLog, false, UpAxis::kY, false},
                      Case{{64, 1030, 1}, DensityMapping::kGamma, true, UpAxis::kZ, true},
                      Case{{40, 33, 70}, DensityMapping::kSqrt, false, UpAxis::kY, true},
                      Case{{70, 70, 70}, DensityMapping::kLinear, true, UpAxis::kZ, false}));

// Fog volumes (zeros inactive) are streamed; compare with a grid built by
// OpenVDB's accessor and written by its writer.
TEST(VdbStream, FogVolumeMatchesBuiltGrid) {
  vdb_internal::InitOpenVdb();
  testing::TempDir dir;
  FloatVolume vol;
  vol.frame.resolution = {21, 17, 30};
  vol.frame.bounds = {{0, 0, 0}, {2, 1.7, 3}};
  vol.values.assign(size_t(vol.frame.resolution.Volume()), 0.f);
  std::mt19937 rng(5);
  for (float& v : vol.values)
    if (rng() % 3 == 0) v = float(rng() % 1000) / 999.f;
  const Metadata meta = {{"nimbus_seed", int64_t{1}}};
  ASSERT_TRUE(WriteFloatVolumeVdb(dir.path() / "s.vdb", vol, meta).ok());
  // The reference: the same grid through OpenVDB's accessor and writer.
  auto ref = ReadVdbFile(dir.path() / "s.vdb");
  ASSERT_TRUE(ref.ok()) << ref.status();
  openvdb::GridPtrVecPtr grids = vdb_internal::ReadAllGrids(dir.path() / "s.vdb");
  auto read = openvdb::gridPtrCast<openvdb::FloatGrid>((*grids)[0]);
  auto built = openvdb::FloatGrid::create();
  built->setName(read->getName());
  built->setGridClass(read->getGridClass());
  built->setTransform(read->transform().copy());
  for (auto it = read->beginMeta(); it != read->endMeta(); ++it)
    if (it->first.rfind("file_", 0) != 0) built->insertMeta(it->first, *it->second);
  auto acc = built->getAccessor();
  const Int3 r = vol.frame.resolution;
  size_t i = 0;
  for (int x = 0; x < r.x; ++x)
    for (int y = 0; y < r.y; ++y)
      for (int z = 0; z < r.z; ++z, ++i)
        if (vol.values[i] != 0.f) acc.setValue(openvdb::Coord(x, y, z), vol.values[i]);
  ASSERT_TRUE(
      vdb_internal::WriteGridsAtomically(dir.path() / "w.vdb", openvdb::GridPtrVec{built}).ok());
  EXPECT_EQ(Slurp(dir.path() / "s.vdb"), Slurp(dir.path() / "w.vdb"));
}

}  // namespace
}  // namespace nimbus
