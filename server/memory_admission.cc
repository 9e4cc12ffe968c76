#include "server/memory_admission.h"

#include <algorithm>
#include <cstdio>
#include <variant>

#include "absl/strings/str_cat.h"
#include "core/base/overloaded.h"
#include "core/base/status_macros.h"
#include "core/grid/contact_sheet.h"
#include "core/jelly/jelly_render.h"
#include "core/sets/set_source_price.h"

namespace nimbus::server {

namespace {

using absl::StrCat;

std::string GiB(uint64_t bytes) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.2f GiB", double(bytes) / double(uint64_t{1} << 30));
  return buf;
}

// A chaos game's peak. When the geometric bound is above 1 GiB (or the
// limit), a pilot run of 2^21 points (10-40 ms) measures the tiles the
// attractor really touches, so thin fractals on huge grids are admitted at
// what they will hold.
struct ChaosEstimate {
  ChaosGameMemory memory;
  uint64_t pilot_samples = 0;
};

ChaosEstimate EstimateChaosGame(const ChaosGameParams& params, int threads,
                                const DensityOptions& density, const spec::Limits& limits,
                                Interrupter* interrupter) {
  constexpr uint64_t kPilotSamples = uint64_t{1} << 21;
  constexpr uint64_t kPilotAbove = uint64_t{1} << 30;
  const uint64_t per_voxel = OutputBytesPerVoxel(density);
  ChaosEstimate e{ChaosGame::EstimateMemory(params, threads, per_voxel), 0};
  if (e.memory.peak() <= std::min(limits.max_memory_bytes, kPilotAbove)) return e;
  auto census = ChaosGame::Pilot(params, kPilotSamples, interrupter);
  if (!census.ok()) return e;
  e.pilot_samples = census->samples;
  e.memory = ChaosGame::EstimateMemory(params, threads, per_voxel, census->estimate);
  return e;
}

absl::StatusOr<MemoryAdmission> CheckChaos(const ChaosEstimate& e, uint64_t extra, int threads,
                                           const spec::Limits& limits) {
  const uint64_t peak = e.memory.peak() + extra;
  if (peak > limits.max_memory_bytes)
    return absl::ResourceExhaustedError(StrCat(
        "grid.resolution: the chaos game needs up to ", GiB(peak), " of memory (",
        GiB(e.memory.accumulation), " to accumulate on ", threads, " threads, ",
        GiB(e.memory.output), " to write",
        e.pilot_samples ? StrCat(", measured by a pilot run of ", e.pilot_samples, " points")
                        : "",
        "); the server limit is ", GiB(limits.max_memory_bytes)));
  return MemoryAdmission{peak, e.pilot_samples};
}

// Per median map: its set and its closest-point field; per step: the
// current and next sets, a field over the moving set and image scratch;
// the output counts; the book's page cache.
uint64_t SetIfsBytes(const SetIfsPlan& plan, Int3 r) {
  uint64_t field_maps = 0;
  for (const SetMapPlan& m : plan.maps)
    field_maps += m.kind == SetMapKind::kMedian || m.kind == SetMapKind::kRotatedMedian;
  const uint64_t voxels = uint64_t(r.Volume());
  const uint64_t set_bytes = (uint64_t(r.x + 63) / 64) * 8 * uint64_t(r.y) * uint64_t(r.z);
  uint64_t bytes = field_maps * (voxels * 4 + set_bytes) + plan.maps.size() * set_bytes +
                   voxels * 8 + set_bytes * 6 + CountGrid::MaxMemoryBytes(r);
  if (plan.book) bytes += plan.book_cache_bytes;
  return bytes;
}


// The costliest mesh to voxelise among `sources` (they are built one at a
// time), with the top-level source that holds it.
struct MeshPrice {
  uint64_t bytes = 0;
  const SetSourcePlan* source = nullptr;
  /// `rest` plus this price, saturated (an absurd mesh prices at 2^64 - 1).
  uint64_t Plus(uint64_t rest) const {
    return bytes > UINT64_MAX - rest ? UINT64_MAX : rest + bytes;
  }
};

MeshPrice PriceMeshes(const std::vector<const SetSourcePlan*>& sources, const GridFrame& frame,
                      int threads) {
  MeshPrice price;
  for (const SetSourcePlan* s : sources) {
    const uint64_t b = SetSourceBuildBytes(*s, frame, threads);
    if (b > price.bytes) price = {b, s};
  }
  return price;
}

// Over the limit: the mesh's field when voxelising it is at least half the
// job, else `field`.
absl::Status OverLimit(const std::string& field, const std::string& what, uint64_t bytes,
                       const MeshPrice& mesh, const spec::Limits& limits) {
  if (mesh.source != nullptr && mesh.bytes >= bytes / 2)
    return absl::ResourceExhaustedError(StrCat(
        mesh.source->field, ": voxelising its mesh takes up to ", GiB(mesh.bytes), " of ",
        GiB(bytes), " of memory (the triangles fanned out of its polygons, and the voxels "
        "each meets); the server limit is ", GiB(limits.max_memory_bytes)));
  return absl::ResourceExhaustedError(StrCat(field, ": ", what, " needs up to ", GiB(bytes),
                                             " of memory; the server limit is ",
                                             GiB(limits.max_memory_bytes)));
}

absl::StatusOr<MemoryAdmission> AdmitSetIfs(const JobPlan& plan, const SetIfsPlan& s,
                                            const spec::Limits& limits, int threads) {
  std::vector<const SetSourcePlan*> sources;
  if (s.start) sources.push_back(&*s.start);
  for (const SetMapPlan& m : s.maps)
    if (m.condensation) sources.push_back(&*m.condensation);
  const MeshPrice mesh = PriceMeshes(sources, plan.frame, threads);
  const uint64_t bytes = mesh.Plus(SetIfsBytes(s, plan.frame.resolution));
  if (bytes > limits.max_memory_bytes)
    return OverLimit("grid.resolution", "the job", bytes, mesh, limits);
  return MemoryAdmission{bytes, 0};
}

// A fractal field: the frame being computed and frame 1 kept for the main
// result (4 bytes a voxel each), the VDB tree built from one (~4.5 bytes a
// voxel at worst), per thread the node planes and folded channels of one
// y-z cross-section, and a shape's distance (4), feature transforms (2 x 4)
// and sets. A terrain's level set is a full volume too.
uint64_t FractalFieldBytes(const FractalFieldPlan& k, Int3 r, int threads) {
  const uint64_t voxels = uint64_t(r.Volume());
  const uint64_t section = uint64_t(r.y + 4) * uint64_t(r.z + 4) * sizeof(float);
  uint64_t bytes = voxels * 4 * 2 + voxels * 9 / 2 + uint64_t(std::max(threads, 1)) * section * 16;
  if (k.output == FieldOutputKind::kTerrain) bytes += uint64_t(r.x) * uint64_t(r.y) * 12;
  if (k.shape) bytes += voxels * (4 + 8) + 2 * ((uint64_t(r.x + 63) / 64) * 8 * uint64_t(r.y) * r.z);
  return bytes;
}

absl::StatusOr<MemoryAdmission> AdmitFractalField(const JobPlan& plan, const FractalFieldPlan& k,
                                                  const spec::Limits& limits, int threads) {
  const MeshPrice mesh =
      k.shape ? PriceMeshes({&k.shape->source}, plan.frame, threads) : MeshPrice{};
  const uint64_t bytes = mesh.Plus(FractalFieldBytes(k, plan.frame.resolution, threads));
  if (bytes > limits.max_memory_bytes)
    return OverLimit("grid.resolution", "the fractal field", bytes, mesh, limits);
  return MemoryAdmission{bytes, 0};
}

// A jelly frame: the leaf buffers (VRR levels, this frame's and the last
// frame's leaves), the voxel order for velocities, the counts, and the
// written grids (density and v) on at most one voxel per leaf.
absl::StatusOr<MemoryAdmission> AdmitJelly(const JobPlan& plan, const JellyPlan& k,
                                           const spec::Limits& limits) {
  const Int3 r = plan.frame.resolution;
  const uint64_t leaves = k.render.mode == JellyRenderMode::kVrr
                              ? VrrLeafCount(k.sim.bodies.size(), k.render.depth,
                                             k.render.start_points.size())
                              : k.render.points;
  const uint64_t voxels = std::min<uint64_t>(leaves, uint64_t(r.Volume()));
  const uint64_t bytes = leaves * (4 * sizeof(Vec3) + 16) + CountGrid::MaxMemoryBytes(r) +
                         voxels * (OutputBytesPerVoxel(plan.density) + 3 * sizeof(float) + 32);
  if (bytes > limits.max_memory_bytes)
    return absl::ResourceExhaustedError(StrCat("jelly.depth: the job needs up to ", GiB(bytes),
                                               " of memory for ", leaves,
                                               " leaves per frame; the server limit is ",
                                               GiB(limits.max_memory_bytes)));
  return MemoryAdmission{bytes, 0};
}

// Point IFS kinds: one engine runs at a time, so the run bounds the job,
// plus `extra` (a component grid's accumulator).
absl::StatusOr<MemoryAdmission> AdmitPointRun(const JobPlan& plan, const ChaosGameParams& run,
                                              uint64_t extra, const spec::Limits& limits,
                                              int threads, Interrupter* interrupter) {
  const ChaosEstimate e = EstimateChaosGame(run, threads, plan.density, limits, interrupter);
  return CheckChaos(e, extra, threads, limits);
}

// A picture's pass: its counters (every tile of the supersampled picture
// on every thread at worst) and the developed picture's float arrays.
uint64_t PictureBytes(const JobPlan& plan, const ChaosGamePlan& k, int threads) {
  if (!k.image) return 0;
  const ImageJob& im = *k.image;
  const int h =
      im.height > 0 ? im.height : DefaultImageHeight(im.view, plan.frame.bounds, im.width);
  ChaosGameParams p = k.params;
  p.image.emplace();
  p.image->width = im.width * im.supersample;
  p.image->height = h * im.supersample;
  const uint64_t pixels = uint64_t(im.width) * uint64_t(h);
  // Density and colour, RGB, the glow's copy: 32 bytes per output pixel.
  return ChaosGame::EstimateMemory(p, threads, 0).peak() + pixels * 32;
}

// An exploration: one thumbnail's chaos game and pilot at a time, its
// developed pixels (density, colour, RGB and the glow's copy: 32 bytes a
// pixel), the kept thumbnails (12 bytes a pixel) and the sheet (12, plus 3
// for the PNG rows).
absl::StatusOr<MemoryAdmission> AdmitExplore(const ExplorePlan& k, const spec::Limits& limits,
                                             int threads) {
  const ExploreParams& p = k.params;
  ChaosGameParams game;
  game.ifs.maps.resize(size_t(p.draw.max_maps));
  game.iterations = p.thumbnail_iterations;
  game.color = p.color;
  game.frame.resolution = {p.thumbnail_size, p.thumbnail_size, 1};
  game.image.emplace();
  game.image->width = game.image->height = p.thumbnail_size;
  const uint64_t pixels = uint64_t(p.thumbnail_size) * uint64_t(p.thumbnail_size);
  const SheetLayout sheet = ContactSheetLayout(p.count, p.thumbnail_size, k.columns);
  const uint64_t bytes = ChaosGame::EstimateMemory(game, threads, 0).peak() +
                         p.frame.pilot_iterations * 3 * sizeof(double) + pixels * 32 +
                         uint64_t(p.count) * pixels * 12 +
                         uint64_t(sheet.width()) * uint64_t(sheet.height()) * 15;
  if (bytes > limits.max_memory_bytes)
    return absl::ResourceExhaustedError(StrCat(
        "explore.count: the exploration needs up to ", GiB(bytes),
        " of memory; the server limit is ", GiB(limits.max_memory_bytes)));
  return MemoryAdmission{bytes, 0};
}

}  // namespace

absl::StatusOr<MemoryAdmission> AdmitMemory(const JobPlan& plan, const spec::Limits& limits,
                                            int threads, Interrupter* interrupter) {
  // One price per job kind: a new kind does not compile until it has one.
  return std::visit(
      Overloaded{
          [&](const ChaosGamePlan& k) {
            return AdmitPointRun(plan, k.params, PictureBytes(plan, k, threads), limits,
                                 threads, interrupter);
          },
          [&](const IfsMatrixPlan& k) {
            const uint64_t extra = k.component_grid == ComponentGridType::kNone
                                       ? 0
                                       : ComponentAccumulator::MaxMemoryBytes(plan.frame.resolution);
            return AdmitPointRun(plan, k.run, extra, limits, threads, interrupter);
          },
          [&](const SetIfsPlan& k) { return AdmitSetIfs(plan, k, limits, threads); },
          [&](const FractalFieldPlan& k) { return AdmitFractalField(plan, k, limits, threads); },
          [&](const JellyPlan& k) { return AdmitJelly(plan, k, limits); },
          [&](const ExplorePlan& k) { return AdmitExplore(k, limits, threads); }},
      plan.kind);
}

}  // namespace nimbus::server
