// The component grid: labels of the dominant component per voxel, written
// as a float grid next to the density (so every OpenVDB reader opens the
// result) and, for COMPONENT_GRID_INT, as an Int32 grid in a side file.
#include "core/matrix/component_grid.h"

#include <gtest/gtest.h>

#include <algorithm>

#include "core/base/sha256.h"
#include "core/io/vdb_io.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

GridFrame Frame() { return {{20, 9, 40}, {{0, 0, 0}, {2, 0.9, 4}}}; }

// Two components: label 0 alone at (1,1,1); both at (3,4,5) with equal
// counts, a tie kept by 0; label 1 alone at (3,4,6) and ahead at (10,2,30).
ComponentAccumulator TwoComponents() {
  const GridFrame f = Frame();
  ComponentAccumulator acc(f.resolution);
  CountGrid a(f.resolution), b(f.resolution);
  a.Add(1, 1, 1, 3);
  a.Add(3, 4, 5, 2);
  a.Add(10, 2, 30, 1);
  b.Add(3, 4, 5, 2);
  b.Add(3, 4, 6, 7);
  b.Add(10, 2, 30, 5);
  acc.Add(0, a);
  acc.Add(1, b);
  return acc;
}

size_t Index(Int3 r, int x, int y, int z) { return (size_t(x) * r.y + y) * r.z + z; }

void ExpectLabels(const std::vector<int32_t>& labels) {
  const Int3 r = Frame().resolution;
  EXPECT_EQ(labels[Index(r, 1, 1, 1)], 0);
  EXPECT_EQ(labels[Index(r, 3, 4, 5)], 0);
  EXPECT_EQ(labels[Index(r, 3, 4, 6)], 1);
  EXPECT_EQ(labels[Index(r, 10, 2, 30)], 1);
  EXPECT_EQ(std::count(labels.begin(), labels.end(), -1), int64_t(labels.size()) - 4);
}

TEST(ComponentGrid, AccumulatorKeepsTheDominantLabel) {
  const ComponentAccumulator acc = TwoComponents();
  EXPECT_EQ(acc.LabelAt(3, 4, 5), 0);
  EXPECT_EQ(acc.LabelAt(10, 2, 30), 1);
  EXPECT_EQ(acc.LabelAt(0, 0, 0), -1);
  EXPECT_EQ(acc.density().Get(10, 2, 30), 6u);
  EXPECT_EQ(acc.VoxelsPerLabel(), (std::vector<uint64_t>{2, 2}));
}

TEST(ComponentGrid, BothTypesPutAFloatGridInTheResult) {
  testing::TempDir dir;
  const ComponentAccumulator acc = TwoComponents();
  for (ComponentGridType type : {ComponentGridType::kFloat, ComponentGridType::kInt}) {
    const auto path = dir / (type == ComponentGridType::kInt ? "int.vdb" : "float.vdb");
    ASSERT_TRUE(WriteDensityAndComponentVdb(path, acc, Frame(), {}, type, {}).ok());
    // The generic float reader sees it: the file holds no Int32 grid.
    auto as_float = ReadVdbFile(path, "component");
    ASSERT_TRUE(as_float.ok()) << as_float.status();
    EXPECT_EQ(as_float->At(10, 2, 30), 1.f);
    EXPECT_EQ(as_float->At(1, 1, 1), 0.f);
    auto labels = ReadComponentGrid(path, Frame().resolution);
    ASSERT_TRUE(labels.ok()) << labels.status();
    ExpectLabels(*labels);
    auto density = ReadVdbFile(path);
    ASSERT_TRUE(density.ok()) << density.status();
    EXPECT_FLOAT_EQ(density->At(10, 2, 30), 6.f / 7.f);
  }
  // Without a side path the two types give the same bytes.
  EXPECT_EQ(*Sha256File(dir / "int.vdb"), *Sha256File(dir / "float.vdb"));
}

TEST(ComponentGrid, IntTypeWritesTheInt32GridToTheSideFile) {
  testing::TempDir dir;
  const ComponentAccumulator acc = TwoComponents();
  const auto main = dir / "tree.vdb", side = dir / "tree.component.vdb";
  ASSERT_TRUE(
      WriteDensityAndComponentVdb(main, acc, Frame(), {}, ComponentGridType::kInt, {}, side).ok());
  auto from_side = ReadComponentGrid(side, Frame().resolution);
  ASSERT_TRUE(from_side.ok()) << from_side.status();
  ExpectLabels(*from_side);
  // The side file holds the Int32 grid alone, so no float reader finds it.
  EXPECT_EQ(ReadVdbFile(side, "component").status().code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(ReadVdbFile(side).status().code(), absl::StatusCode::kNotFound);
  auto in_main = ReadComponentGrid(main, Frame().resolution);
  ASSERT_TRUE(in_main.ok());
  EXPECT_EQ(*in_main, *from_side);
  auto component = ReadVdbFile(main, "component");
  ASSERT_TRUE(component.ok());
  const MetaValue* named = component->Find("nimbus_component_int32_file");
  ASSERT_NE(named, nullptr);
  EXPECT_EQ(std::get<std::string>(*named), "tree.component.vdb");
  // The float type ignores the side path.
  const auto other = dir / "other.component.vdb";
  ASSERT_TRUE(WriteDensityAndComponentVdb(dir / "f.vdb", acc, Frame(), {},
                                          ComponentGridType::kFloat, {}, other)
                  .ok());
  EXPECT_FALSE(std::filesystem::exists(other));
}

TEST(ComponentGrid, NoGridIsNotFound) {
  testing::TempDir dir;
  ASSERT_TRUE(WriteDensityAndComponentVdb(dir / "d.vdb", TwoComponents(), Frame(), {},
                                          ComponentGridType::kNone, {})
                  .ok());
  EXPECT_EQ(ReadComponentGrid(dir / "d.vdb", Frame().resolution).status().code(),
            absl::StatusCode::kNotFound);
}

}  // namespace
}  // namespace nimbus
