#include "core/sets/voxelize.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <fstream>

#include "core/io/mesh_io.h"
#include "core/sets/shapes.h"
#include "core/io/vdb_io.h"
#include "core/sets/set_source_price.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

GridFrame Cube(int n) { return {{n, n, n}, {{-1, -1, -1}, {1, 1, 1}}}; }

TriangleMesh Example(const std::string& name) {
  absl::StatusOr<TriangleMesh> m = LoadMesh(testing::SourcePath("examples/meshes/" + name));
  EXPECT_TRUE(m.ok()) << m.status();
  return *m;
}

int64_t SymmetricDifference(const VoxelSet& a, const VoxelSet& b) {
  return (a - b).Count() + (b - a).Count();
}

Int3 VoxelOf(const GridFrame& f, Vec3 world) {
  const Vec3 h = f.VoxelSize();
  return {int(std::floor((world.x - f.bounds.min.x) / h.x)),
          int(std::floor((world.y - f.bounds.min.y) / h.y)),
          int(std::floor((world.z - f.bounds.min.z) / h.z))};
}

TriangleMesh Tetrahedron() {
  TriangleMesh m;
  m.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  m.triangles = {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}};
  return m;
}

TEST(MeshTopology, CountsBoundaryNonManifoldAndFlippedEdges) {
  TriangleMesh t = Tetrahedron();
  MeshTopology topo = AnalyzeTopology(t);
  EXPECT_TRUE(topo.watertight());
  EXPECT_EQ(topo.edges, 6);
  t.triangles.pop_back();  // open one face
  topo = AnalyzeTopology(t);
  EXPECT_FALSE(topo.watertight());
  EXPECT_EQ(topo.boundary_edges, 3);
  t = Tetrahedron();
  t.vertices.push_back({-1, -1, 5});
  t.triangles.push_back({0, 1, 4});  // a fin on edge 0-1
  EXPECT_EQ(AnalyzeTopology(t).nonmanifold_edges, 1);
  t = Tetrahedron();
  std::swap(t.triangles[3][0], t.triangles[3][1]);  // flip one face
  topo = AnalyzeTopology(t);
  EXPECT_TRUE(topo.watertight());
  EXPECT_EQ(topo.inconsistent_edges, 3);
}

TEST(MeshTopology, WeldsDuplicatedVertices) {
  // Binary STL stores every corner separately; welding restores the cow.
  const TriangleMesh cow = Example("cow.obj");
  const absl::StatusOr<TriangleMesh> soup =
      ParseStl(SerializeMesh(cow, MeshFormat::kStlBinary), "cow.stl");
  ASSERT_TRUE(soup.ok());
  EXPECT_EQ(soup->vertices.size(), 3 * cow.triangles.size());
  const MeshTopology topo = AnalyzeTopology(*soup);
  EXPECT_TRUE(topo.watertight());
  EXPECT_EQ(topo.welded_vertices, 2903);
  EXPECT_FALSE(AnalyzeTopology(Example("teapot.obj")).watertight());
  EXPECT_GT(AnalyzeTopology(Example("teapot.obj")).boundary_edges, 0);
}

TEST(Voxelize, LevelSetAndRayVoteAgreeOnAWatertightMesh) {
  const GridFrame f = Cube(64);
  const TriangleMesh cow = Example("cow.obj");
  VoxelizeOptions o;
  o.fit = true;
  const absl::StatusOr<VoxelizeResult> auto_result = VoxelizeMesh(cow, f, o);
  ASSERT_TRUE(auto_result.ok()) << auto_result.status();
  EXPECT_TRUE(auto_result->watertight);
  EXPECT_EQ(auto_result->method, InteriorMethod::kLevelSet);
  o.method = InteriorMethod::kRayVote;
  o.shell_voxels = 0;
  const VoxelizeResult vote = *VoxelizeMesh(cow, f, o);
  const int64_t n = auto_result->interior.Count();
  EXPECT_GT(n, 5000);
  // Only voxels whose centres lie almost on the surface may differ.
  EXPECT_LT(SymmetricDifference(auto_result->interior, vote.interior), n / 50);
}

TEST(Voxelize, FitCentresAndScalesPreservingAspect) {
  const GridFrame f = Cube(64);
  VoxelizeOptions o;
  o.fit = true;
  o.fit_margin_voxels = 2;
  const VoxelizeResult r = *VoxelizeMesh(Example("cow.obj"), f, o);
  const VoxelBox box = *r.interior.BoundingBox();
  // The cow is longest along x: it spans the grid less the margins.
  EXPECT_NEAR(box.Size().x, 60, 1);
  EXPECT_NEAR(0.5 * (box.min.x + box.max.x), 31.5, 1);
  EXPECT_NEAR(0.5 * (box.min.y + box.max.y), 31.5, 1);
  // Aspect kept: the cow's mesh extents are 10.44 x 6.40 x 3.40.
  EXPECT_NEAR(double(box.Size().y) / box.Size().x, 6.40 / 10.44, 0.05);
  EXPECT_NEAR(r.placement.m[0][0], r.placement.m[1][1], 1e-12);
  // Without fitting, a mesh away from the bounds leaves nothing: an error.
  const absl::StatusOr<VoxelizeResult> far =
      VoxelizeMesh(Example("cow.obj"), {{16, 16, 16}, {{50, 50, 50}, {51, 51, 51}}}, {});
  EXPECT_EQ(far.status().code(), absl::StatusCode::kInvalidArgument);
}

TEST(Voxelize, AnisotropicVoxelsMeasureTheSameVolume) {
  const TriangleMesh cow = Example("cow.obj");
  VoxelizeOptions o;
  o.fit = true;
  o.fit_margin_voxels = 0;
  // Same world box, voxels of 1/64, 1/32 and 1/48 of it along x, y, z.
  const GridFrame iso = Cube(64);
  const GridFrame aniso{{64, 32, 48}, iso.bounds};
  const double v_iso = std::pow(2.0 / 64, 3);
  const Vec3 h = aniso.VoxelSize();
  const double v_aniso = h.x * h.y * h.z;
  const double a = VoxelizeMesh(cow, iso, o)->interior.Count() * v_iso;
  const double b = VoxelizeMesh(cow, aniso, o)->interior.Count() * v_aniso;
  EXPECT_NEAR(b / a, 1.0, 0.06);
}

TEST(Voxelize, HolesStillGiveASensibleInterior) {
  const GridFrame f = Cube(64);
  VoxelizeOptions o;
  o.fit = true;
  // Cut two patches out of the watertight cow, each a few voxels wide.
  const TriangleMesh cow = Example("cow.obj");
  TriangleMesh holed = cow;
  holed.triangles.clear();
  const Vec3 centres[2] = {cow.vertices[100], cow.vertices[2000]};
  for (const auto& t : cow.triangles) {
    const Vec3 c = (1.0 / 3) * (cow.vertices[t[0]] + cow.vertices[t[1]] + cow.vertices[t[2]]);
    if (Length(c - centres[0]) > 0.5 && Length(c - centres[1]) > 0.5) holed.triangles.push_back(t);
  }
  ASSERT_LT(holed.triangles.size(), cow.triangles.size() - 10);
  const VoxelSet reference = VoxelizeMesh(cow, f, o)->interior;
  const absl::StatusOr<VoxelizeResult> r = VoxelizeMesh(holed, f, o);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_FALSE(r->watertight);
  EXPECT_GT(r->topology.boundary_edges, 0);
  EXPECT_EQ(r->method, InteriorMethod::kRayVote);
  // The vote recovers the closed cow's interior.
  EXPECT_LT(SymmetricDifference(reference, r->interior), reference.Count() / 50);
  // A shell option thickens it by the surface voxels.
  VoxelizeOptions shell = o;
  shell.shell_voxels = 0.5;
  const VoxelSet thick = VoxelizeMesh(holed, f, shell)->interior;
  EXPECT_EQ((r->interior - thick).Count(), 0);
  EXPECT_GT(thick.Count(), r->interior.Count());
  // An open sheet keeps its surface voxels.
  TriangleMesh sheet;
  sheet.vertices = {{-0.5, -0.5, 0.01}, {0.5, -0.5, 0.01}, {0.5, 0.5, 0.01}, {-0.5, 0.5, 0.01}};
  sheet.triangles = {{0, 1, 2}, {0, 2, 3}};
  const absl::StatusOr<VoxelizeResult> flat = VoxelizeMesh(sheet, f, {});
  ASSERT_TRUE(flat.ok()) << flat.status();
  EXPECT_EQ(flat->interior.BoundingBox()->Size().z, 1);
  EXPECT_NEAR(flat->interior.Count(), 32 * 32, 64);
}

TEST(Voxelize, OpenTeapotIsFilledAndReportedNotWatertight) {
  const GridFrame f = Cube(64);
  VoxelizeOptions o;
  o.fit = true;
  const absl::StatusOr<VoxelizeResult> r =
      LoadAndVoxelize(testing::SourcePath("examples/meshes/teapot.obj"), f, o);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_FALSE(r->watertight);
  EXPECT_EQ(r->method, InteriorMethod::kRayVote);
  // The body (a solid of revolution about y, radius up to ~2 around y = 1.2
  // in mesh units) is filled; air beside and above it is not.
  auto inside = [&](Vec3 mesh_point) {
    return r->interior.Contains(VoxelOf(f, r->placement.Apply(mesh_point)));
  };
  EXPECT_TRUE(inside({0, 1.2, 0}));
  EXPECT_TRUE(inside({1.2, 1.0, 0.6}));
  EXPECT_TRUE(inside({0, 2.0, -1.0}));
  EXPECT_FALSE(inside({0, 1.2, 2.5}));
  EXPECT_FALSE(inside({0, 3.6, 0}));
  EXPECT_FALSE(inside({-2.4, 0.3, 1.8}));
  // A solid body: the interior fills most of the body's cylinder slice.
  const Int3 c = VoxelOf(f, r->placement.Apply({0, 1.2, 0}));
  int filled = 0, total = 0;
  for (int dz = -6; dz <= 6; ++dz)
    for (int dx = -6; dx <= 6; ++dx) {
      ++total;
      filled += r->interior.Contains({c.x + dx, c.y, c.z + dz});
    }
  EXPECT_GT(filled, total * 9 / 10);
}

class CancelAtOnce : public Interrupter {
 public:
  bool WasInterrupted(uint64_t, uint64_t) override { return true; }
};

TEST(Voxelize, HonoursTheInterrupter) {
  CancelAtOnce cancel;
  VoxelizeOptions o;
  o.fit = true;
  const absl::StatusOr<VoxelizeResult> r = VoxelizeMesh(Example("cow.obj"), Cube(32), o, &cancel);
  EXPECT_EQ(r.status().code(), absl::StatusCode::kCancelled);
  o.method = InteriorMethod::kRayVote;
  EXPECT_EQ(VoxelizeMesh(Example("cow.obj"), Cube(32), o, &cancel).status().code(),
            absl::StatusCode::kCancelled);
}

// Lattice rays along `axis` strictly inside triangle q (index space, where
// the ray vote casts a ray through every whole (u, v)), counted one by one.
int64_t RaysInside(const Vec3 q[3], int axis, Int3 res) {
  const int ua = (axis + 1) % 3, va = (axis + 2) % 3;
  int64_t n = 0;
  for (int iu = 0; iu < res[ua]; ++iu)
    for (int iv = 0; iv < res[va]; ++iv) {
      int positive = 0, negative = 0;
      for (int k = 0; k < 3; ++k) {
        const Vec3& a = q[k];
        const Vec3& b = q[(k + 1) % 3];
        const double e = (b[ua] - a[ua]) * (iv - a[va]) - (b[va] - a[va]) * (iu - a[ua]);
        positive += e > 0, negative += e < 0;
      }
      n += positive == 3 || negative == 3;
    }
  return n;
}

// Every copy of a triangle is voxelised again: the ray vote keeps a
// 12-byte crossing for each lattice ray through each copy, and the price
// must cover that (and stay within a few times of it).
TEST(VoxelizePrice, CoversEveryLatticeRayOfEveryCopy) {
  const GridFrame frame = Cube(64);
  TriangleMesh one;
  one.vertices = {{-0.9, -0.9, -0.5}, {0.9, -0.7, 0.1}, {-0.6, 0.9, 0.6}};
  one.triangles = {{0, 1, 2}};
  TriangleMesh copies = one;
  copies.triangles.assign(1000, {0, 1, 2});
  const Vec3 h = frame.VoxelSize();
  Vec3 q[3];
  for (int k = 0; k < 3; ++k)
    for (int a = 0; a < 3; ++a) q[k][a] = (one.vertices[k][a] - frame.bounds.min[a]) / h[a] - 0.5;
  int64_t rays = 0;
  for (int axis = 0; axis < 3; ++axis) rays = std::max(rays, RaysInside(q, axis, frame.resolution));
  ASSERT_GT(rays, 1000);  // a triangle across most of the grid
  const double extra = double(VoxelizeMemoryBytes(copies, Affine3::Identity(), frame, 0, 1)) -
                       double(VoxelizeMemoryBytes(one, Affine3::Identity(), frame, 0, 1));
  EXPECT_GE(extra, 999.0 * 12 * double(rays));
  EXPECT_LE(extra, 999.0 * 48 * double(rays));
}

TEST(GridSet, LevelSetRoundTripMatchesTheMeshInterior) {
  testing::TempDir dir;
  const GridFrame f = Cube(40);
  TriangleMesh cow = Example("cow.obj");
  const Affine3 fit = FitPlacement(cow.GetBounds(), f, 2);
  for (Vec3& v : cow.vertices) v = fit.Apply(v);
  ASSERT_TRUE(SaveMeshLevelSet(cow, f, dir / "cow.vdb").ok());
  auto mesh_set = VoxelizeMesh(cow, f);
  ASSERT_TRUE(mesh_set.ok()) << mesh_set.status();
  auto grid_set = LoadGridSet(dir / "cow.vdb", f);
  ASSERT_TRUE(grid_set.ok()) << grid_set.status();
  EXPECT_EQ(SymmetricDifference(*grid_set, mesh_set->interior), 0);
  // Read on a finer grid, the same solid: about 8x the voxels.
  auto fine = LoadGridSet(dir / "cow.vdb", Cube(80));
  ASSERT_TRUE(fine.ok());
  EXPECT_NEAR(double(fine->Count()) / double(grid_set->Count()), 8.0, 1.6);
}

TEST(GridSet, FogVolumeUsesTheThreshold) {
  testing::TempDir dir;
  const GridFrame f = Cube(24);
  auto ball = SphereSet(f, {0, 0, 0}, 0.6);
  auto small = SphereSet(f, {0, 0, 0}, 0.3);
  ASSERT_TRUE(ball.ok() && small.ok());
  CountGrid counts(f.resolution);
  ball->ForEach([&](int x, int y, int z) { counts.Add(x, y, z); });
  small->ForEach([&](int x, int y, int z) { counts.Add(x, y, z, 3); });  // density 1 inside
  ASSERT_TRUE(WriteDensityVdb(dir / "fog.vdb", counts, f, {}, {}).ok());
  auto all = LoadGridSet(dir / "fog.vdb", f, {"", 0.1});
  auto dense = LoadGridSet(dir / "fog.vdb", f, {"density", 0.5});
  ASSERT_TRUE(all.ok() && dense.ok()) << all.status() << dense.status();
  EXPECT_EQ(*all, *ball);
  EXPECT_EQ(*dense, *small);
  EXPECT_EQ(LoadGridSet(dir / "fog.vdb", f, {"nope", 0.5}).status().code(),
            absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(LoadGridSet(dir / "none.vdb", f).status().code(), absl::StatusCode::kNotFound);
  std::ofstream(dir / "junk.vdb") << "not a vdb";
  EXPECT_EQ(LoadGridSet(dir / "junk.vdb", f).status().code(), absl::StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace nimbus
