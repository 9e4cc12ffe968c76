#include "core/sets/set_source.h"

#include <algorithm>

#include "absl/strings/str_cat.h"
#include "core/sets/set_source_price.h"
#include "core/sets/voxelize.h"

namespace nimbus {

using absl::StrCat;

namespace {

// Fit first (in the mesh's units), then the spec's own transform.
Affine3 MeshPlacement(const SetSourcePlan& s, const TriangleMesh& mesh, const GridFrame& frame) {
  const Affine3 fit =
      s.fit ? FitPlacement(mesh.GetBounds(), frame, s.fit_margin_voxels) : Affine3::Identity();
  return s.transform * fit;
}

}  // namespace

uint64_t SetSourceBuildBytes(const SetSourcePlan& s, const GridFrame& frame, int threads) {
  uint64_t bytes = 0;
  if (s.kind == SetSourcePlan::Kind::kMesh && s.mesh)
    bytes = VoxelizeMemoryBytes(*s.mesh, MeshPlacement(s, *s.mesh, frame), frame, s.shell_voxels,
                                threads);
  for (const SetSourcePlan& p : s.parts)
    bytes = std::max(bytes, SetSourceBuildBytes(p, frame, threads));
  return bytes;
}

absl::StatusOr<VoxelSet> BuildSetSource(const SetSourcePlan& s, const GridFrame& frame,
                                        SetBuildCache* cache, Interrupter* interrupter) {
  if (cache) {
    auto it = cache->sets.find(s.cache_key);
    if (it != cache->sets.end()) return it->second;
  }
  absl::StatusOr<VoxelSet> set;
  switch (s.kind) {
    case SetSourcePlan::Kind::kMesh: {
      TriangleMesh mesh = *s.mesh;
      const Affine3 place = MeshPlacement(s, mesh, frame);
      for (Vec3& v : mesh.vertices) v = place.Apply(v);
      VoxelizeOptions o;
      o.shell_voxels = s.shell_voxels;
      auto r = VoxelizeMesh(mesh, frame, o, interrupter);
      if (!r.ok()) {
        set = r.status();
      } else {
        set = std::move(r->interior);
      }
      break;
    }
    case SetSourcePlan::Kind::kGrid: {
      GridSetOptions o;
      o.grid_name = s.grid_name;
      o.threshold = s.threshold;
      set = LoadGridSet(s.file, frame, o, interrupter);
      break;
    }
    case SetSourcePlan::Kind::kSphere:
      set = SphereSet(frame, s.center, s.radius);
      break;
    case SetSourcePlan::Kind::kBox:
      set = BoxSet(frame, s.box);
      break;
    case SetSourcePlan::Kind::kTorus:
      set = TorusSet(frame, s.center, s.axis, s.major_radius, s.minor_radius);
      break;
    case SetSourcePlan::Kind::kRandomBalls: {
      auto region = BuildSetSource(s.parts[0], frame, cache, interrupter);
      if (!region.ok()) return region.status();
      set = RandomBallsInside(*region, frame, s.balls);
      break;
    }
    case SetSourcePlan::Kind::kUnion: {
      VoxelSet u(frame.resolution);
      for (const SetSourcePlan& p : s.parts) {
        auto part = BuildSetSource(p, frame, cache, interrupter);
        if (!part.ok()) return part.status();
        u |= *part;
      }
      set = std::move(u);
      break;
    }
  }
  if (!set.ok()) {
    if (absl::IsCancelled(set.status())) return set.status();
    const std::string file = s.file_label.empty() ? "" : StrCat(s.file_label, ": ");
    return absl::Status(set.status().code(), StrCat(s.field, ": ", file, set.status().message()));
  }
  if (set->Empty())
    return absl::InvalidArgumentError(
        StrCat(s.field,
               ": the set has no voxels on this grid (it lies outside the bounds or is "
               "thinner than a voxel)"));
  if (cache) cache->sets.emplace(s.cache_key, *set);
  return set;
}

}  // namespace nimbus
