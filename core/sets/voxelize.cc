#include "core/sets/voxelize.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <unordered_map>

#include "absl/strings/str_cat.h"
#include "core/base/status_macros.h"
#include "core/io/vdb_module.h"
#include "core/sets/set_source_price.h"
#include "core/sets/voxelize_vdb_module.h"

namespace nimbus {
namespace {

struct VecHash {
  size_t operator()(const Vec3& v) const {
    uint64_t b[3];
    std::memcpy(b, &v.x, 8);
    std::memcpy(b + 1, &v.y, 8);
    std::memcpy(b + 2, &v.z, 8);
    uint64_t h = b[0] * 0x9e3779b97f4a7c15ULL;
    h ^= b[1] + 0x632be59bd9b4e019ULL + (h << 6) + (h >> 2);
    h ^= b[2] + 0xd1342543de82ef95ULL + (h << 6) + (h >> 2);
    return size_t(h);
  }
};

}  // namespace

MeshTopology AnalyzeTopology(const TriangleMesh& mesh) {
  MeshTopology topo;
  std::unordered_map<Vec3, uint32_t, VecHash> ids;
  ids.reserve(mesh.vertices.size());
  std::vector<uint32_t> weld(mesh.vertices.size());
  for (size_t i = 0; i < mesh.vertices.size(); ++i)
    weld[i] = ids.emplace(mesh.vertices[i], uint32_t(ids.size())).first->second;
  topo.welded_vertices = int64_t(ids.size());
  // Undirected edge key in the high bits, direction (a < b) in bit 0.
  struct Edge {
    uint64_t key;
    bool forward;
  };
  std::vector<Edge> edges;
  edges.reserve(mesh.triangles.size() * 3);
  for (const auto& t : mesh.triangles) {
    const uint32_t v[3] = {weld[t[0]], weld[t[1]], weld[t[2]]};
    if (v[0] == v[1] || v[1] == v[2] || v[0] == v[2]) {
      ++topo.degenerate_triangles;
      continue;
    }
    for (int k = 0; k < 3; ++k) {
      const uint32_t a = v[k], b = v[(k + 1) % 3];
      edges.push_back({(uint64_t(std::min(a, b)) << 32) | std::max(a, b), a < b});
    }
  }
  std::sort(edges.begin(), edges.end(), [](const Edge& a, const Edge& b) {
    return a.key != b.key ? a.key < b.key : a.forward < b.forward;
  });
  for (size_t i = 0; i < edges.size();) {
    size_t j = i;
    while (j < edges.size() && edges[j].key == edges[i].key) ++j;
    ++topo.edges;
    const size_t uses = j - i;
    if (uses == 1) {
      ++topo.boundary_edges;
    } else if (uses > 2) {
      ++topo.nonmanifold_edges;
    } else if (edges[i].forward == edges[i + 1].forward) {
      ++topo.inconsistent_edges;
    }
    i = j;
  }
  return topo;
}

Affine3 FitPlacement(const Bounds& mesh, const GridFrame& frame, double margin_voxels) {
  const Vec3 ms = mesh.Size(), fs = frame.bounds.Size(), h = frame.VoxelSize();
  double scale = std::numeric_limits<double>::infinity();
  for (int a = 0; a < 3; ++a) {
    if (!(ms[a] > 0)) continue;
    const double room = std::max(fs[a] - 2 * margin_voxels * h[a], 0.5 * fs[a]);
    scale = std::min(scale, room / ms[a]);
  }
  if (!std::isfinite(scale)) scale = 1;  // a single point: just centre it
  const Vec3 mc = 0.5 * (mesh.min + mesh.max);
  const Vec3 fc = 0.5 * (frame.bounds.min + frame.bounds.max);
  return Affine3::Translate(fc) * Affine3::Scale({scale, scale, scale}) *
         Affine3::Translate(-1.0 * mc);
}

namespace {

// Lattice rays (per axis) and narrow-band voxels one triangle may touch.
struct TriangleReach {
  double rays[3] = {0, 0, 0};
  double band = 0;
};

// `q` in index units (voxel size 1); `band` in voxels.
TriangleReach Reach(const Vec3 q[3], double band, Int3 res) {
  TriangleReach r;
  double perimeter3 = 0;
  for (int k = 0; k < 3; ++k) perimeter3 += Length(q[(k + 1) % 3] - q[k]);
  const double area3 = 0.5 * Length(Cross(q[1] - q[0], q[2] - q[0]));
  for (int axis = 0; axis < 3; ++axis) {
    const int ua = (axis + 1) % 3, va = (axis + 2) % 3;
    const double area = 0.5 * std::abs((q[1][ua] - q[0][ua]) * (q[2][va] - q[0][va]) -
                                       (q[1][va] - q[0][va]) * (q[2][ua] - q[0][ua]));
    double perimeter = 0;
    for (int k = 0; k < 3; ++k)
      perimeter += std::hypot(q[(k + 1) % 3][ua] - q[k][ua], q[(k + 1) % 3][va] - q[k][va]);
    // Lattice points in a convex region: at most area + perimeter / 2 + 1.
    r.rays[axis] = std::min(area + perimeter / 2 + 1, double(res[ua]) * double(res[va]));
  }
  r.band = (area3 + perimeter3 * band + M_PI * band * band) * 2 * band + 1;
  return r;
}

}  // namespace

uint64_t VoxelizeMemoryBytes(const TriangleMesh& mesh, const Affine3& placement,
                             const GridFrame& frame, double shell_voxels, int threads) {
  const Vec3 h = frame.VoxelSize();
  const Int3 res = frame.resolution;
  auto index = [&](uint32_t v) {
    const Vec3 w = placement.Apply(mesh.vertices[v]);
    return Vec3{w.x / h.x, w.y / h.y, w.z / h.z};
  };
  // The level set's band is 2 voxels; the ray vote's shell at least half a voxel.
  const double band = std::max(2.0, shell_voxels + 1.0);
  double rays[3] = {0, 0, 0}, band_voxels = 0;
  for (const auto& t : mesh.triangles) {
    const Vec3 q[3] = {index(t[0]), index(t[1]), index(t[2])};
    const TriangleReach r = Reach(q, band, res);
    for (int a = 0; a < 3; ++a) rays[a] += r.rays[a];
    band_voxels += r.band;
  }
  const double v = double(mesh.vertices.size()), t = double(mesh.triangles.size());
  const double voxels = double(res.x) * double(res.y) * double(res.z);
  const double set_bytes = std::ceil(res.x / 64.0) * 8 * double(res.y) * double(res.z);
  // Two meshes (the plan's and the placed copy), the topology's weld map and
  // edges, the index-space points, meshToVolume's copies.
  double bytes = 2 * (24 * v + 12 * t) + 80 * v + 48 * t + 24 * v + 24 * v + 12 * t;
  bytes += 7 * set_bytes;                                   // the votes and the interior
  bytes += 24 * std::max({rays[0], rays[1], rays[2]});      // 12-byte crossings, doubling
  bytes += 9 * std::min(band_voxels, std::max(threads, 1) * voxels);  // distance, index, id
  return bytes >= 1.8e19 ? UINT64_MAX : uint64_t(bytes);
}

// Voxelisation and grid sets are OpenVDB's: they run in the module
// (voxelize_vdb.cc).
namespace {

absl::StatusOr<const VoxelizeVdbTable*> VoxelizeVdb() {
  static const absl::StatusOr<const VoxelizeVdbTable*> table =
      LoadVdbModuleTable<VoxelizeVdbTable>(kVoxelizeVdbEntry, kVoxelizeVdbAbi);
  return table;
}

}  // namespace

absl::StatusOr<VoxelizeResult> VoxelizeMesh(const TriangleMesh& mesh, const GridFrame& frame,
                                            const VoxelizeOptions& options,
                                            Interrupter* interrupter) {
  NIMBUS_ASSIGN_OR_RETURN(const VoxelizeVdbTable* vdb, VoxelizeVdb());
  return vdb->voxelize_mesh(mesh, frame, options, interrupter);
}

absl::StatusOr<VoxelizeResult> LoadAndVoxelize(const std::filesystem::path& path,
                                               const GridFrame& frame,
                                               const VoxelizeOptions& options,
                                               Interrupter* interrupter) {
  NIMBUS_ASSIGN_OR_RETURN(const TriangleMesh mesh, LoadMesh(path));
  absl::StatusOr<VoxelizeResult> r = VoxelizeMesh(mesh, frame, options, interrupter);
  if (!r.ok()) {
    return absl::Status(r.status().code(), absl::StrCat(path.string(), ": ", r.status().message()));
  }
  return r;
}

absl::Status SaveMeshLevelSet(const TriangleMesh& mesh, const GridFrame& frame,
                              const std::filesystem::path& path, const std::string& grid_name) {
  NIMBUS_ASSIGN_OR_RETURN(const VoxelizeVdbTable* vdb, VoxelizeVdb());
  return vdb->save_mesh_level_set(mesh, frame, path, grid_name);
}

absl::StatusOr<VoxelSet> LoadGridSet(const std::filesystem::path& path, const GridFrame& frame,
                                     const GridSetOptions& options, Interrupter* interrupter) {
  NIMBUS_ASSIGN_OR_RETURN(const VoxelizeVdbTable* vdb, VoxelizeVdb());
  return vdb->load_grid_set(path, frame, options, interrupter);
}

}  // namespace nimbus
