// Every kind of file Nimbus writes opens in Debian's pyopenvdb, which wraps
// only float, bool and Vec3f grids and refuses a whole file (metadata
// included) when any grid has another type. The files are written with the
// core writers the runners use; tests/python/check_vdb_files.py then reads
// every grid's metadata and every grid and compares them with a manifest
// whose values come from Nimbus' own readers.
#include <gtest/gtest.h>

#include <cstdlib>
#include <fstream>
#include <sstream>

#include "core/io/vdb_io.h"
#include "core/matrix/component_grid.h"
#include "core/sets/set_ifs.h"
#include "core/sets/set_maps.h"
#include "core/sets/shapes.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

constexpr char kPython[] = "/usr/bin/python3";

GridFrame Frame() { return {{20, 9, 40}, {{-1, 0, 2}, {1, 0.9, 6}}}; }

// One grid's expectations as a manifest entry (JSON).
class GridWant {
 public:
  GridWant(const std::string& name, const std::string& type, const std::string& cls,
           int64_t active)
      : head_("{\"name\": \"" + name + "\", \"type\": \"" + type + "\", \"class\": \"" + cls +
              "\", \"active\": " + std::to_string(active)) {}
  GridWant& Meta(const std::string& key, const std::string& json_value) {
    meta_ += (meta_.empty() ? "" : ", ") + ("\"" + key + "\": " + json_value);
    return *this;
  }
  GridWant& Value(int x, int y, int z, double v) {
    std::ostringstream s;
    s.precision(9);
    s << "[" << x << ", " << y << ", " << z << ", " << v << "]";
    values_ += (values_.empty() ? "" : ", ") + s.str();
    return *this;
  }
  GridWant& Value(int x, int y, int z, const Vec3& v) {
    std::ostringstream s;
    s.precision(9);
    s << "[" << x << ", " << y << ", " << z << ", [" << v.x << ", " << v.y << ", " << v.z << "]]";
    values_ += (values_.empty() ? "" : ", ") + s.str();
    return *this;
  }
  std::string Json() const {
    return head_ + ", \"meta\": {" + meta_ + "}, \"values\": [" + values_ + "]}";
  }

 private:
  std::string head_, meta_, values_;
};

std::string FileEntry(const std::string& file, const std::vector<GridWant>& grids) {
  std::string out = "{\"file\": \"" + file + "\", \"grids\": [";
  for (size_t i = 0; i < grids.size(); ++i) out += (i ? ", " : "") + grids[i].Json();
  return out + "]}";
}

// The frame every grid records, as pyopenvdb returns it (a tuple -> list).
GridWant Framed(GridWant g) {
  const GridFrame f = Frame();
  g.Meta("nimbus_resolution", "[20, 9, 40]");
  std::ostringstream lo, hi;
  lo << "[" << f.bounds.min.x << ", " << f.bounds.min.y << ", " << f.bounds.min.z << "]";
  hi << "[" << f.bounds.max.x << ", " << f.bounds.max.y << ", " << f.bounds.max.z << "]";
  return std::move(g.Meta("nimbus_bounds_min", lo.str()).Meta("nimbus_bounds_max", hi.str()));
}

// Counts 4, 2, 1 at three voxels: densities 1, 0.5, 0.25 exactly.
CountGrid ThreeVoxels(bool color) {
  CountGrid c(Frame().resolution, color);
  const auto add = [&](int x, int y, int z, uint32_t n, uint32_t color16) {
    c.AddKey(CountGrid::WithColor(c.Key(x, y, z), color ? color16 : 0), n);
  };
  add(0, 0, 0, 4, 0);
  add(19, 8, 39, 2, CountGrid::kColorScale);
  add(7, 3, 33, 1, CountGrid::kColorScale / 2);
  return c;
}

GridWant DensityWant() {
  return std::move(Framed(GridWant("density", "FloatGrid", "fog volume", 3))
                       .Meta("nimbus_seed", "42")
                       .Meta("nimbus_spec_hash", "\"abc\"")
                       .Value(0, 0, 0, 1.0)
                       .Value(19, 8, 39, 0.5)
                       .Value(7, 3, 33, 0.25));
}

std::string DensityOnly(const testing::TempDir& dir) {
  const Metadata meta = {{"nimbus_seed", int64_t{42}}, {"nimbus_spec_hash", std::string("abc")}};
  EXPECT_TRUE(WriteDensityVdb(dir / "density.vdb", ThreeVoxels(false), Frame(), {}, meta).ok());
  return FileEntry("density.vdb", {DensityWant()});
}

// Density, Cd, address and float raw counts: every optional float grid.
std::string WithColour(const testing::TempDir& dir) {
  DensityOptions o;
  o.color = true;
  o.address_grid = true;
  o.raw_counts = RawCounts::kFloat;
  const Metadata meta = {{"nimbus_seed", int64_t{42}}, {"nimbus_spec_hash", std::string("abc")}};
  const auto path = dir / "colour.vdb";
  EXPECT_TRUE(WriteDensityVdb(path, ThreeVoxels(true), Frame(), o, meta).ok());
  auto cd = ReadVec3VdbFile(path);
  EXPECT_TRUE(cd.ok()) << cd.status();
  if (!cd.ok()) return {};
  GridWant cd_want = Framed(GridWant("Cd", "Vec3SGrid", "unknown", 3));
  for (const Int3 v : {Int3{0, 0, 0}, Int3{19, 8, 39}, Int3{7, 3, 33}})
    cd_want.Value(v.x, v.y, v.z, cd->At(v.x, v.y, v.z));
  GridWant address = Framed(GridWant("address", "FloatGrid", "unknown", 3));
  address.Value(0, 0, 0, 0.0).Value(19, 8, 39, 1.0);
  GridWant counts = Framed(GridWant("counts", "FloatGrid", "unknown", 3));
  counts.Value(0, 0, 0, 4.0).Value(19, 8, 39, 2.0).Value(7, 3, 33, 1.0);
  return FileEntry("colour.vdb", {DensityWant(), std::move(cd_want), std::move(address),
                                  std::move(counts)});
}

std::string WithComponents(const testing::TempDir& dir, ComponentGridType type,
                           const std::string& file) {
  ComponentAccumulator acc(Frame().resolution);
  CountGrid a(Frame().resolution), b(Frame().resolution);
  a.Add(0, 0, 0, 4);
  a.Add(7, 3, 33, 1);
  b.Add(19, 8, 39, 2);
  acc.Add(0, a);
  acc.Add(1, b);
  const Metadata meta = {{"nimbus_seed", int64_t{42}}, {"nimbus_spec_hash", std::string("abc")}};
  const std::string side_name = std::filesystem::path(file).stem().string() + ".component.vdb";
  const auto side = dir / side_name;
  EXPECT_TRUE(WriteDensityAndComponentVdb(dir / file, acc, Frame(), {}, type, meta, side).ok());
  GridWant component = Framed(GridWant("component", "FloatGrid", "unknown", 3));
  component.Value(0, 0, 0, 0.0).Value(7, 3, 33, 0.0).Value(19, 8, 39, 1.0);
  if (type == ComponentGridType::kInt)
    component.Meta("nimbus_component_int32_file", "\"" + side_name + "\"");
  return FileEntry(file, {DensityWant(), std::move(component)});
}

// Page 1 of a set-IFS book, written as the runner writes pages.
std::string SetIfsPage(const testing::TempDir& dir) {
  const GridFrame f = Frame();
  auto a = SphereSet(f, {-0.5, 0.45, 3}, 0.3);
  auto b = BoxSet(f, {{0.2, 0.2, 4}, {0.8, 0.7, 5.5}});
  EXPECT_TRUE(a.ok() && b.ok());
  const SetIfs ifs{f, {*MakeMedianMap(f, *a), *MakeMedianMap(f, *b)}, {}, {}};
  BookOptions o;
  o.depth = 1;
  std::string entry;
  auto on_page = [&](uint64_t index, const std::string& address,
                     const VoxelSet& page) -> absl::Status {
    if (index != 0) return absl::OkStatus();
    CountGrid counts(f.resolution);
    Int3 member{-1, -1, -1};
    page.ForEach([&](int x, int y, int z) {
      counts.Add(x, y, z);
      member = {x, y, z};
    });
    const Metadata meta = {{"nimbus_book_address", address}, {"nimbus_book_page", int64_t{1}}};
    if (auto st = WriteDensityVdb(dir / "book.0001.vdb", counts, f, {}, meta); !st.ok()) return st;
    GridWant g = Framed(GridWant("density", "FloatGrid", "fog volume", page.Count()));
    g.Meta("nimbus_book_address", "\"" + address + "\"").Meta("nimbus_book_page", "1");
    g.Value(member.x, member.y, member.z, 1.0);
    entry = FileEntry("book.0001.vdb", {std::move(g)});
    return absl::OkStatus();
  };
  EXPECT_TRUE(RunBook(ifs, o, on_page).ok());
  EXPECT_FALSE(entry.empty());
  return entry;
}

TEST(PyOpenVdb, ReadsEveryKindOfFileNimbusWrites) {
  if (std::system((std::string(kPython) + " -c 'import pyopenvdb' >/dev/null 2>&1").c_str()) != 0)
    GTEST_SKIP() << kPython << " cannot import pyopenvdb (Debian: apt install python3-openvdb; "
                 << "scripts/install_deps.sh does)";
  testing::TempDir dir;
  const std::vector<std::string> entries = {
      DensityOnly(dir), WithColour(dir),
      WithComponents(dir, ComponentGridType::kFloat, "component_float.vdb"),
      WithComponents(dir, ComponentGridType::kInt, "component_int.vdb"), SetIfsPage(dir)};
  ASSERT_FALSE(HasFailure());
  std::string manifest = "{\"files\": [";
  for (size_t i = 0; i < entries.size(); ++i) manifest += (i ? ",\n" : "\n") + entries[i];
  manifest += "\n]}\n";
  std::ofstream(dir / "manifest.json") << manifest;

  const auto out = dir / "python.log";
  const std::string cmd = std::string(kPython) + " " NIMBUS_SOURCE_DIR
                          "/tests/python/check_vdb_files.py '" +
                          (dir / "manifest.json").string() + "' > '" + out.string() + "' 2>&1";
  const int rc = std::system(cmd.c_str());
  std::ifstream log(out);
  const std::string text((std::istreambuf_iterator<char>(log)), {});
  EXPECT_EQ(rc, 0) << text << "\nmanifest:\n" << manifest;
  EXPECT_NE(text.find("checked 5 files, 0 problems"), std::string::npos) << text;
}

}  // namespace
}  // namespace nimbus
