// The OpenVDB side of voxelize.h, in the libnimbus_vdb.so module
// (core/io/vdb_module.h): mesh voxelisation (meshToVolume for watertight
// meshes, the ray vote and its distance shell otherwise), mesh level sets
// written as grids, and grids read back as sets.
#include <openvdb/io/File.h>
#include <openvdb/openvdb.h>
#include <openvdb/tools/MeshToVolume.h>
#include <openvdb/util/NullInterrupter.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <string_view>

#include "absl/strings/str_cat.h"
#include "core/base/status_macros.h"
#include "core/io/vdb_internal.h"
#include "core/sets/voxelize.h"
#include "core/sets/voxelize_vdb_module.h"

namespace nimbus::vdb_impl {
namespace {

// Forwards OpenVDB's percentage polls to a nimbus Interrupter.
class VdbInterrupter final : public openvdb::util::NullInterrupter {
 public:
  explicit VdbInterrupter(Interrupter& i) : i_(i) {}
  bool wasInterrupted(int percent = -1) override {
    if (i_.WasInterrupted(percent < 0 ? 0 : uint64_t(percent), 100)) cancelled_ = true;
    return cancelled_;
  }
  bool cancelled() const { return cancelled_; }

 private:
  Interrupter& i_;
  bool cancelled_ = false;
};


// Mesh vertices in the frame's index space, where voxel (i, j, k) has its
// centre at (i, j, k): the convention of OpenVDB's mesh adapters.
std::vector<Vec3> IndexSpacePoints(const TriangleMesh& mesh, const Affine3& placement,
                                   const GridFrame& frame) {
  const Vec3 h = frame.VoxelSize();
  std::vector<Vec3> pts(mesh.vertices.size());
  for (size_t i = 0; i < pts.size(); ++i) {
    const Vec3 w = placement.Apply(mesh.vertices[i]);
    pts[i] = {(w.x - frame.bounds.min.x) / h.x - 0.5, (w.y - frame.bounds.min.y) / h.y - 0.5,
              (w.z - frame.bounds.min.z) / h.z - 0.5};
  }
  return pts;
}

// Runs openvdb::tools::meshToVolume on index-space points.
absl::StatusOr<openvdb::FloatGrid::Ptr> MeshToVdb(const TriangleMesh& mesh,
                                                  const std::vector<Vec3>& pts,
                                                  const GridFrame& frame, float band, int flags,
                                                  Interrupter& intr) {
  std::vector<openvdb::Vec3s> points(pts.size());
  for (size_t i = 0; i < pts.size(); ++i)
    points[i] = openvdb::Vec3s(float(pts[i].x), float(pts[i].y), float(pts[i].z));
  std::vector<openvdb::Vec3I> tris(mesh.triangles.size());
  for (size_t i = 0; i < tris.size(); ++i)
    tris[i] = openvdb::Vec3I(mesh.triangles[i][0], mesh.triangles[i][1], mesh.triangles[i][2]);
  const Vec3 h = frame.VoxelSize();
  const Vec3 origin = frame.VoxelCenter({0, 0, 0});
  VdbInterrupter vdb_intr(intr);
  // Core never lets an exception out: OpenVDB's become statuses here.
  try {
    openvdb::initialize();
    // Index-to-world map of the lattice; non-uniform voxel sizes are a
    // plain per-axis scale. The points are already in index space, which is
    // where meshToVolume measures its bands (in voxels).
    openvdb::math::Transform xform(std::make_shared<openvdb::math::ScaleTranslateMap>(
        openvdb::Vec3d(h.x, h.y, h.z), openvdb::Vec3d(origin.x, origin.y, origin.z)));
    openvdb::tools::QuadAndTriangleDataAdapter<openvdb::Vec3s, openvdb::Vec3I> adapter(points,
                                                                                       tris);
    openvdb::FloatGrid::Ptr grid = openvdb::tools::meshToVolume<openvdb::FloatGrid>(
        vdb_intr, adapter, xform, band, band, flags);
    if (vdb_intr.cancelled()) return absl::CancelledError("voxelisation interrupted");
    if (!grid) return absl::InternalError("meshToVolume returned no grid");
    return grid;
  } catch (const std::exception& e) {
    return absl::InternalError(absl::StrCat("meshToVolume failed: ", e.what()));
  }
}

// Clips an OpenVDB box to the lattice and fills it.
void FillBox(const openvdb::CoordBBox& bb, VoxelSet& set) {
  const Int3 r = set.resolution();
  const int x0 = std::max(bb.min().x(), 0), x1 = std::min(bb.max().x(), r.x - 1);
  const int y0 = std::max(bb.min().y(), 0), y1 = std::min(bb.max().y(), r.y - 1);
  const int z0 = std::max(bb.min().z(), 0), z1 = std::min(bb.max().z(), r.z - 1);
  for (int z = z0; z <= z1; ++z)
    for (int y = y0; y <= y1; ++y) set.SetSpan(x0, x1, y, z);
}

// Level-set interior: negative values, both narrow-band voxels and the
// inactive interior tiles that meshToVolume's sign flood fill produced.
absl::Status LevelSetInterior(const TriangleMesh& mesh, const std::vector<Vec3>& pts,
                              const GridFrame& frame, Interrupter& intr, VoxelSet& out) {
  NIMBUS_ASSIGN_OR_RETURN(const openvdb::FloatGrid::Ptr grid,
                          MeshToVdb(mesh, pts, frame, 2.0f, 0, intr));
  for (auto it = grid->cbeginValueAll(); it; ++it) {
    if (!(*it < 0)) continue;
    openvdb::CoordBBox bb;
    it.getBoundingBox(bb);
    FillBox(bb, out);
  }
  return absl::OkStatus();
}

// One signed ray crossing: ray index, position along the ray (index units),
// +1 entering / -1 leaving when travelling towards +axis.
struct Crossing {
  uint32_t ray;
  float t;
  int32_t sign;
};

// Winding numbers along every lattice ray parallel to `axis`, counted from
// the low end into `from_low` and from the high end into `from_high`
// (voxels with a non-zero count are set). On a closed surface both agree;
// a hole corrupts one direction of the rays through it only.
void AxisVotes(const TriangleMesh& mesh, const std::vector<Vec3>& pts, int axis, Int3 res,
               VoxelSet& from_low, VoxelSet& from_high) {
  const int ua = (axis + 1) % 3, va = (axis + 2) % 3;
  const int nu = res[ua], nv = res[va], n = res[axis];
  std::vector<Crossing> crossings;
  for (const auto& tri : mesh.triangles) {
    Vec3 q[3] = {pts[tri[0]], pts[tri[1]], pts[tri[2]]};
    // Projected doubled area = the normal's component along the axis.
    double area = (q[1][ua] - q[0][ua]) * (q[2][va] - q[0][va]) -
                  (q[1][va] - q[0][va]) * (q[2][ua] - q[0][ua]);
    if (area == 0 || !std::isfinite(area)) continue;
    const int32_t sign = area < 0 ? 1 : -1;
    if (area < 0) {
      std::swap(q[1], q[2]);
      area = -area;
    }
    const double umin = std::min({q[0][ua], q[1][ua], q[2][ua]});
    const double umax = std::max({q[0][ua], q[1][ua], q[2][ua]});
    const double vmin = std::min({q[0][va], q[1][va], q[2][va]});
    const double vmax = std::max({q[0][va], q[1][va], q[2][va]});
    const int iu0 = std::max(0, int(std::ceil(umin))),
              iu1 = std::min(nu - 1, int(std::floor(umax)));
    const int iv0 = std::max(0, int(std::ceil(vmin))),
              iv1 = std::min(nv - 1, int(std::floor(vmax)));
    for (int iv = iv0; iv <= iv1; ++iv) {
      for (int iu = iu0; iu <= iu1; ++iu) {
        double e[3];
        bool inside = true;
        for (int k = 0; k < 3 && inside; ++k) {
          // Edge opposite corner k, from a to b; counter-clockwise order.
          const Vec3& a = q[(k + 1) % 3];
          const Vec3& b = q[(k + 2) % 3];
          const double du = b[ua] - a[ua], dv = b[va] - a[va];
          e[k] = du * (iv - a[va]) - dv * (iu - a[ua]);
          // Points on an edge belong to exactly one of the two triangles
          // sharing it (the edge runs opposite ways in them).
          const bool owns = dv < 0 || (dv == 0 && du > 0);
          inside = e[k] > 0 || (e[k] == 0 && owns);
        }
        if (!inside) continue;
        const double t = (e[0] * q[0][axis] + e[1] * q[1][axis] + e[2] * q[2][axis]) / area;
        crossings.push_back({uint32_t(iv) * uint32_t(nu) + uint32_t(iu), float(t), sign});
      }
    }
  }
  std::sort(crossings.begin(), crossings.end(), [](const Crossing& a, const Crossing& b) {
    return a.ray != b.ray ? a.ray < b.ray : a.t < b.t;
  });
  auto mark = [&](VoxelSet& set, int iu, int iv, int k0, int k1) {
    if (k0 > k1) return;
    if (axis == 0) {
      set.SetSpan(k0, k1, iu, iv);  // (u, v) = (y, z)
      return;
    }
    for (int k = k0; k <= k1; ++k) {
      // (u, v) is (z, x) for rays along y and (x, y) for rays along z.
      set.Set(axis == 1 ? Int3{iv, k, iu} : Int3{iu, iv, k});
    }
  };
  for (size_t i = 0; i < crossings.size();) {
    size_t j = i;
    int total = 0;
    while (j < crossings.size() && crossings[j].ray == crossings[i].ray)
      total += crossings[j++].sign;
    const int iu = int(crossings[i].ray % uint32_t(nu)), iv = int(crossings[i].ray / uint32_t(nu));
    // Voxel k has passed crossing c when c.t <= k.
    int w = 0;
    for (size_t c = i; c < j; ++c) {
      w += crossings[c].sign;
      const int k0 = std::max(0, int(std::ceil(crossings[c].t)));
      const int k1 = c + 1 < j ? std::min(n - 1, int(std::ceil(crossings[c + 1].t)) - 1) : n - 1;
      if (w != 0) mark(from_low, iu, iv, k0, k1);
      if (w - total != 0) mark(from_high, iu, iv, k0, k1);
    }
    if (total != 0) {  // before the first crossing only the high count can be non-zero
      const int k1 = std::min(n - 1, int(std::ceil(crossings[i].t)) - 1);
      mark(from_high, iu, iv, 0, k1);
    }
    i = j;
  }
}

// Voxels with at least four of six votes.
VoxelSet Majority(const std::vector<VoxelSet>& votes) {
  VoxelSet out(votes[0].resolution());
  std::vector<uint64_t>& o = out.mutable_words();
  for (size_t w = 0; w < o.size(); ++w) {
    uint64_t s0 = 0, s1 = 0, s2 = 0;  // bit-sliced counter
    for (const VoxelSet& v : votes) {
      const uint64_t x = v.words()[w];
      const uint64_t c0 = s0 & x;
      s0 ^= x;
      const uint64_t c1 = s1 & c0;
      s1 ^= c0;
      s2 |= c1;
    }
    o[w] = s2;  // count >= 4
  }
  return out;
}

absl::Status RayVoteInterior(const TriangleMesh& mesh, const std::vector<Vec3>& pts,
                             const GridFrame& frame, double shell, Interrupter& intr,
                             VoxelSet& out) {
  const Int3 res = frame.resolution;
  std::vector<VoxelSet> votes(6, VoxelSet(res));
  for (int axis = 0; axis < 3; ++axis) {
    if (intr.WasInterrupted(uint64_t(axis), 4))
      return absl::CancelledError("voxelisation interrupted");
    AxisVotes(mesh, pts, axis, res, votes[2 * axis], votes[2 * axis + 1]);
  }
  out = Majority(votes);
  // An open sheet (no volume to vote on) still leaves its surface voxels.
  if (out.Empty()) shell = std::max(shell, 0.5);
  if (shell > 0) {
    NIMBUS_ASSIGN_OR_RETURN(const openvdb::FloatGrid::Ptr grid,
                            MeshToVdb(mesh, pts, frame, float(shell + 1.0),
                                      openvdb::tools::UNSIGNED_DISTANCE_FIELD, intr));
    // meshToVolume scales index-space distances by the first voxel size.
    const double limit = shell * frame.VoxelSize().x;
    for (auto it = grid->cbeginValueOn(); it; ++it) {
      if (*it > limit) continue;
      const openvdb::Coord c = it.getCoord();
      if (out.InBounds(c.x(), c.y(), c.z())) out.Set(c.x(), c.y(), c.z());
    }
  }
  return absl::OkStatus();
}

}  // namespace

absl::StatusOr<VoxelizeResult> VoxelizeMesh(const TriangleMesh& mesh, const GridFrame& frame,
                                            const VoxelizeOptions& options,
                                            Interrupter* interrupter) {
  NIMBUS_RETURN_IF_ERROR(ValidateSetFrame(frame));
  NIMBUS_RETURN_IF_ERROR(ValidateMesh(mesh, "mesh"));
  Interrupter& intr = OrNull(interrupter);
  intr.Start("voxelise mesh");
  VoxelizeResult result;
  result.topology = AnalyzeTopology(mesh);
  result.watertight = result.topology.watertight();
  result.placement = options.fit ? FitPlacement(mesh.GetBounds(), frame, options.fit_margin_voxels)
                                 : Affine3::Identity();
  result.method = options.method;
  if (result.method == InteriorMethod::kAuto)
    result.method = result.watertight ? InteriorMethod::kLevelSet : InteriorMethod::kRayVote;
  const std::vector<Vec3> pts = IndexSpacePoints(mesh, result.placement, frame);
  result.interior = VoxelSet(frame.resolution);
  absl::Status s =
      result.method == InteriorMethod::kLevelSet
          ? LevelSetInterior(mesh, pts, frame, intr, result.interior)
          : RayVoteInterior(mesh, pts, frame, options.shell_voxels, intr, result.interior);
  intr.End();
  if (!s.ok()) return s;
  if (result.interior.Empty()) {
    return absl::InvalidArgumentError(
        "voxelised mesh is empty: it lies outside the grid bounds or is thinner than a voxel "
        "(try fit)");
  }
  return result;
}

absl::Status SaveMeshLevelSet(const TriangleMesh& mesh, const GridFrame& frame,
                              const std::filesystem::path& path, const std::string& grid_name) {
  NIMBUS_RETURN_IF_ERROR(ValidateSetFrame(frame));
  NIMBUS_RETURN_IF_ERROR(ValidateMesh(mesh, "mesh"));
  const std::vector<Vec3> pts = IndexSpacePoints(mesh, Affine3::Identity(), frame);
  NIMBUS_ASSIGN_OR_RETURN(const openvdb::FloatGrid::Ptr grid,
                          MeshToVdb(mesh, pts, frame, 3.0f, 0, OrNull(nullptr)));
  try {
    // meshToVolume already scales distances to world units.
    grid->setGridClass(openvdb::GRID_LEVEL_SET);
    grid->setName(grid_name);
    openvdb::io::File file(path.string());
    file.write({grid});
    file.close();
  } catch (const std::exception& e) {
    return absl::InternalError(absl::StrCat(path.string(), ": cannot write: ", e.what()));
  }
  return vdb_internal::StampContentUuid(path);
}

absl::StatusOr<VoxelSet> LoadGridSet(const std::filesystem::path& path, const GridFrame& frame,
                                     const GridSetOptions& options, Interrupter* interrupter) {
  NIMBUS_RETURN_IF_ERROR(ValidateSetFrame(frame));
  Interrupter& intr = OrNull(interrupter);
  const std::string name = path.string();
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec))
    return absl::NotFoundError(absl::StrCat(name, ": no such file"));
  openvdb::FloatGrid::Ptr grid;
  // Core never lets an exception out: OpenVDB's become statuses here.
  try {
    openvdb::initialize();
    openvdb::io::File file(name);
    file.open();
    std::string chosen = options.grid_name;
    if (chosen.empty()) {
      openvdb::GridPtrVecPtr metas = file.readAllGridMetadata();
      for (const openvdb::GridBase::Ptr& g : *metas)
        if (g->isType<openvdb::FloatGrid>()) {
          chosen = g->getName();
          break;
        }
      if (chosen.empty()) {
        file.close();
        return absl::InvalidArgumentError(absl::StrCat(name, ": holds no float grid"));
      }
    } else if (!file.hasGrid(chosen)) {
      file.close();
      return absl::InvalidArgumentError(absl::StrCat(name, ": no grid named '", chosen, "'"));
    }
    grid = openvdb::gridPtrCast<openvdb::FloatGrid>(file.readGrid(chosen));
    file.close();
    if (!grid)
      return absl::InvalidArgumentError(
          absl::StrCat(name, ": grid '", chosen, "' is not a float grid"));
  } catch (const std::exception& e) {
    // OpenVDB's text can be a gigabyte for a damaged file: keep its start.
    constexpr size_t kMaxWhat = 300;
    const size_t len = ::strnlen(e.what(), kMaxWhat + 1);
    return absl::InvalidArgumentError(
        absl::StrCat(name, ": not a readable VDB file: ",
                     std::string(e.what(), std::min(len, kMaxWhat)),
                     len > kMaxWhat ? "\xe2\x80\xa6" : ""));
  }
  const bool level_set = grid->getGridClass() == openvdb::GRID_LEVEL_SET;
  const float threshold = float(options.threshold);
  VoxelSet set(frame.resolution);
  const Int3 r = frame.resolution;
  intr.Start("sample grid");
  auto acc = grid->getConstAccessor();
  const openvdb::math::Transform& xform = grid->transform();
  for (int z = 0; z < r.z; ++z) {
    if (intr.WasInterrupted(uint64_t(z), uint64_t(r.z))) {
      intr.End();
      return absl::CancelledError("grid sampling interrupted");
    }
    for (int y = 0; y < r.y; ++y)
      for (int x = 0; x < r.x; ++x) {
        const Vec3 c = frame.VoxelCenter({x, y, z});
        const openvdb::Coord ijk = xform.worldToIndexCellCentered(openvdb::Vec3d(c.x, c.y, c.z));
        const float v = acc.getValue(ijk);
        if (level_set ? v < 0.0f : v > threshold) set.Set(x, y, z);
      }
  }
  intr.End();
  if (set.Empty())
    return absl::InvalidArgumentError(
        absl::StrCat(name, ": the grid has no inside voxels within the job's grid bounds"));
  return set;
}

}  // namespace nimbus::vdb_impl

extern "C" __attribute__((visibility("default"))) const nimbus::VoxelizeVdbTable*
NimbusVoxelizeVdb() {
  static const nimbus::VoxelizeVdbTable table{
      nimbus::kVoxelizeVdbAbi, &nimbus::vdb_impl::VoxelizeMesh, &nimbus::vdb_impl::SaveMeshLevelSet,
      &nimbus::vdb_impl::LoadGridSet};
  return &table;
}
