#include "core/chaos/chaos_game.h"

#include <tbb/parallel_for.h>
#include <tbb/task_group.h>

#include <algorithm>
#include <atomic>
#include <bit>
#include <cmath>
#include <thread>

#include "absl/strings/str_cat.h"
#include "core/chaos/affine_walk.h"
#include "core/chaos/key_bins.h"
#include "core/chaos/shared_tiles.h"
#include "core/chaos/tile_bins.h"

namespace nimbus {

static_assert(ChaosGame::kWalkers == walk::kLanes);

namespace {
// Bytes per key in a worker's KeyBins.
constexpr uint64_t kKeyBytes = sizeof(uint64_t);

Vec3 RandomPoint(Rng& rng, const Bounds& b) {
  // Three draws in x, y, z order: the argument order of a braced list is
  // fixed, unlike a function call's.
  return Vec3{rng.Uniform(b.min.x, b.max.x), rng.Uniform(b.min.y, b.max.y),
              rng.Uniform(b.min.z, b.max.z)};
}

bool Planar(const std::vector<Affine3>& maps);
uint64_t ReachableTiles(const ChaosGameParams& p);
size_t BufferEntries(const ChaosGameParams& p, uint64_t reachable_tiles);
uint64_t PoolTiles(const ChaosGameParams& p, bool fast);
bool DirectIncrements(const ChaosGameParams& p, uint64_t pool_tiles);
uint64_t* AlignedTo64(uint64_t* p) {
  return reinterpret_cast<uint64_t*>((reinterpret_cast<uintptr_t>(p) + 63) & ~uintptr_t(63));
}
// The general path's threads share one grid when their keys are packed.
bool SharesPackedGrid(const ChaosGameParams& p, int threads) {
  return !ChaosGame::UsesFastPath(p) && threads > 1 && p.shared_grid.value_or(true) &&
         KeyBins::Packs(p.CountResolution(), p.color.mode != ColorMode::kNone);
}
}  // namespace

struct ChaosGame::Worker {
  CountGrid* grid = nullptr;
  // General path: 64-bit keys (with colour and weight), binned as produced.
  std::unique_ptr<KeyBins> keys;
  // Fast path: 32-bit entries, binned as produced.
  std::unique_ptr<TileBins> bins;
  ChaosGameStats stats;

  void Flush() {
    if (bins) bins->Flush();
    if (keys) keys->Flush();
  }
  // Packed words may stay unfolded between rounds (ChaosGame::partial_counts).
  bool DefersFlush() const { return keys && keys->packed(); }
  // Through the bins: a shared grid's own flag is written under its
  // allocation lock, and the bins read SharedTiles' atomic copy instead.
  bool overflowed() const {
    return bins ? bins->overflowed() : keys ? keys->overflowed() : grid->overflowed();
  }
};

ChaosGame::ChaosGame(ChaosGameParams params, int threads)
    : params_(std::move(params)), threads_(std::max(1, threads)) {}

ChaosGame::~ChaosGame() = default;

absl::StatusOr<std::unique_ptr<ChaosGame>> ChaosGame::Create(ChaosGameParams params, int threads) {
  if (params.ifs.maps.empty()) return absl::InvalidArgumentError("the IFS has no maps");
  const Int3 r = params.frame.resolution;
  if (r.x <= 0 || r.y <= 0 || r.z <= 0)
    return absl::InvalidArgumentError("grid resolution must be positive on every axis");
  const Vec3 size = params.frame.bounds.Size();
  if (!(size.x > 0 && size.y > 0 && size.z > 0))
    return absl::InvalidArgumentError("grid bounds must have max > min on every axis");
  std::unique_ptr<ChaosGame> game(new ChaosGame(std::move(params), threads));
  const ChaosGameParams& p = game->params_;
  const Ifs& ifs = p.ifs;  // the moved-into copy
  if (p.chain) {
    if (p.chain->states.empty()) return absl::InvalidArgumentError("the chain has no states");
    if (p.chain->start_state >= p.chain->states.size())
      return absl::InvalidArgumentError("the chain's start state does not exist");
    for (size_t s = 0; s < p.chain->states.size(); ++s) {
      const ChainState& st = p.chain->states[s];
      if (st.transitions.empty() || st.transitions.size() != st.probabilities.size())
        return absl::InvalidArgumentError(
            absl::StrCat("chain state ", s, " needs transitions with one probability each"));
      for (const ChainTransition& t : st.transitions)
        if (t.map >= ifs.maps.size() || t.next_state >= p.chain->states.size())
          return absl::InvalidArgumentError(
              absl::StrCat("chain state ", s, " has a transition to a missing map or state"));
      game->state_tables_.emplace_back(st.probabilities);
    }
  } else {
    if (ifs.probabilities.size() != ifs.maps.size())
      return absl::InvalidArgumentError("need one probability per map");
    double total = 0;
    for (double q : ifs.probabilities) {
      if (!(q >= 0)) return absl::InvalidArgumentError("probabilities must be >= 0");
      total += q;
    }
    if (!(total > 0)) return absl::InvalidArgumentError("probabilities must not all be 0");
    game->map_table_ = AliasTable(ifs.probabilities);
  }
  if (p.image && (p.splat || p.image->width <= 0 || p.image->height <= 0))
    return absl::InvalidArgumentError("an image needs a positive size and no splatting");
  if (p.color.mode != ColorMode::kNone && !(p.color.blend > 0 && p.color.blend <= 1))
    return absl::InvalidArgumentError("colour blend must be in (0, 1]");
  game->num_chunks_ = NumChunks(p.iterations);
  game->end_chunk_ = p.chunk_end == 0 ? game->num_chunks_ : p.chunk_end;
  if (p.chunk_begin > game->end_chunk_ || game->end_chunk_ > game->num_chunks_)
    return absl::InvalidArgumentError(absl::StrCat("chunk range [", p.chunk_begin, ", ",
                                                   game->end_chunk_, ") is not within the run's ",
                                                   game->num_chunks_, " chunks"));
  game->begin_chunk_ = game->next_chunk_ = p.chunk_begin;
  game->fast_ = UsesFastPath(p);
  game->simd_ = std::min(p.simd.value_or(ActiveSimd()), DetectSimd());
  if (!game->fast_ && !p.chain) {
    const int mode = p.color.mode == ColorMode::kNone ? 0 : p.color.mode == ColorMode::kMap ? 1 : 2;
    game->program_ = FlameProgram(ifs.maps, ifs.final_map, game->map_table_, mode, p.color.blend);
    game->flame_round_ = FlameKernel(game->simd_);
    // Affine maps keep kWalkers walkers, whose streams then hold exactly
    // the draws of the one-walker loop (docs/chaos_game.md).
    const bool affine = ifs.AllAffine() &&
                        (!ifs.final_map || FlameProgram::MapWords(*ifs.final_map) == 0);
    game->flame_walkers_ = affine ? kWalkers : flame::kChunkWalkers;
  }
  for (const PointMap& m : ifs.maps) {
    // Walking in pixel space: one affine map per step, no projection.
    const Affine3 a = p.image ? p.image->view * m.pre * Inverse(p.image->view) : m.pre;
    game->fast_maps_.push_back(a);
    for (const auto& row : a.m)
      game->affine_coef_.insert(game->affine_coef_.end(), row.begin(), row.end());
  }
  game->planar_ = Planar(game->fast_maps_);
  if (game->fast_ && p.chain) {
    FlatChain& f = game->flat_chain_.emplace();
    const std::vector<ChainState>& states = p.chain->states;
    for (size_t s = 0; s < states.size(); ++s) {
      const AliasTable& table = game->state_tables_[s];
      f.state.push_back(f.step.size() | uint64_t(states[s].transitions.size()) << 32);
      for (size_t t = 0; t < states[s].transitions.size(); ++t) {
        const ChainTransition& tr = states[s].transitions[t];
        f.sample.push_back(table.thresholds()[t] | uint64_t(table.aliases()[t]) << 32);
        f.step.push_back(tr.map | uint64_t(states[tr.next_state].plotted ? 1 : 0) << 31 |
                         uint64_t(tr.next_state) << 32);
      }
    }
  }
  // Buffers sized once, never above what EstimateMemory counted.
  const uint64_t pool_tiles = PoolTiles(p, game->fast_);
  const size_t entries = BufferEntries(p, pool_tiles);
  const bool direct = game->fast_ && DirectIncrements(p, pool_tiles);
  const bool shared =
      game->fast_ && !direct && game->threads_ > 1 && p.shared_grid.value_or(true);
  game->AddWorkers(entries, direct, shared);
  if (game->flame_round_ && !p.ifs.arcs && !p.splat) {
    game->flame_plot_ = FlamePlotter(game->simd_);
    game->plot_target_ = MakePlotTarget(p, game->counts_[0]);
    game->plot_target_.planar = game->program_.program().planar;
  }
  if (p.memory_budget > 0) {
    // Each grid gets an equal share of what the budget leaves after the
    // fixed parts (tile tables and buffers).
    const uint64_t fixed = game->MemoryBytes();  // no tiles yet
    const uint64_t free_bytes = p.memory_budget > fixed ? p.memory_budget - fixed : 0;
    const uint64_t tile_bytes = CountGrid::TileBytes(p.color.mode != ColorMode::kNone);
    const uint64_t tiles = free_bytes / uint64_t(game->counts_.size()) / tile_bytes;
    for (CountGrid& g : game->counts_) g.SetTileLimit(size_t(std::max<uint64_t>(tiles, 1)));
  }
  return game;
}

void ChaosGame::AddWorkers(size_t entries, bool direct, bool shared) {
  const ChaosGameParams& p = params_;
  const bool color = p.color.mode != ColorMode::kNone;
  // Packed keys fold into one grid shared by the threads (KeyBins).
  const bool shared_keys = SharesPackedGrid(p, threads_);
  shared_keys_ = shared_keys;
  const int grids = shared || shared_keys ? 1 : threads_;
  // Reserved: workers keep pointers into counts_.
  counts_.reserve(size_t(grids));
  for (int t = 0; t < grids; ++t) counts_.emplace_back(p.CountResolution(), color);
  if (shared) {
    shared_tiles_ = std::make_unique<SharedTiles>(
        counts_[0], uint32_t(TileBins::BinCount(p.CountResolution())));
  }
  for (int t = 0; t < threads_; ++t) {
    auto w = std::make_unique<Worker>();
    CountGrid& grid = counts_[size_t(grids == 1 ? 0 : t)];
    w->grid = &grid;
    // Threads start their flushes at ranges far apart.
    const uint32_t first_range = uint32_t(t) * SharedTiles::kRanges / uint32_t(threads_);
    if (shared)
      w->bins = std::make_unique<TileBins>(*shared_tiles_, grid, entries, first_range);
    else if (fast_ && p.image)  // the kernel walks the picture's pixels
      w->bins = std::make_unique<TileBins>(grid, entries, direct,
                                           Int3{p.image->width, p.image->height, 1},
                                           uint32_t(ImagePlane::kFoldShift));
    else if (fast_)
      w->bins = std::make_unique<TileBins>(grid, entries, direct);
    else
      w->keys = std::make_unique<KeyBins>(grid, entries, p.splat,
                                          shared_keys ? &fold_lock_ : nullptr);
    workers_.push_back(std::move(w));
  }
}

namespace {

// Whether the fast path's maps are a 2D IFS as walk::AffineWalk::planar
// defines it: z's column out of the x and y rows, and z set to one
// constant by every map.
bool Planar(const std::vector<Affine3>& maps) {
  for (const Affine3& a : maps) {
    if (a.m[0][2] != 0 || a.m[1][2] != 0) return false;
    if (a.m[2][0] != 0 || a.m[2][1] != 0 || a.m[2][2] != 0) return false;
    if (a.m[2][3] != maps[0].m[2][3]) return false;  // also false for NaN
  }
  return true;
}

// Tiles of the grid that plotted points can reach. For contractive affine
// maps plotted as they are, the attractor lies in a ball B(c, R) that every
// map sends into itself: |A_i c + b_i - c| + s_i R <= R, s_i the map's
// largest singular value. Walkers enter it to within s_max^warmup times
// their starting distance before they plot. Otherwise: the whole grid.
uint64_t ReachableTiles(const ChaosGameParams& p) {
  const Int3 r = p.CountResolution();
  const uint64_t all = CountGrid::TileCountFor(r);
  if (p.image || p.ifs.final_map || p.ifs.arcs || !p.ifs.AllAffine() || p.ifs.maps.empty())
    return all;
  Vec3 c;
  double s_max = 0;
  for (const PointMap& m : p.ifs.maps) {
    const double s = m.pre.ContractionFactor();
    if (!(s < 1)) return all;
    s_max = std::max(s_max, s);
    Vec3 fixed;  // the map's fixed point, by iteration
    for (int i = 0; i < 2000; ++i) fixed = m.pre.Apply(fixed);
    c = c + fixed;
  }
  c = (1.0 / double(p.ifs.maps.size())) * c;
  double radius = 0;
  for (const PointMap& m : p.ifs.maps)
    radius = std::max(radius, Length(m.pre.Apply(c) - c) / (1 - m.pre.ContractionFactor()));
  const Bounds& b = p.frame.bounds;
  const double start = Length(b.max - b.min) + Length(c - b.min) + radius;
  const Vec3 vs = p.frame.VoxelSize();
  radius += std::pow(s_max, double(p.warmup)) * start + Length(vs);
  if (!std::isfinite(radius)) return all;
  uint64_t tiles = 1;
  const Int3 span = CountGrid::TileSpan(r);  // a folded grid's tiles are 1024 rows high
  for (int a = 0; a < 3; ++a) {
    const int n = r[a];
    const double lo = std::floor((c[a] - radius - b.min[a]) / vs[a]);
    const double hi = std::floor((c[a] + radius - b.min[a]) / vs[a]);
    const int t0 = int(std::clamp(lo, 0.0, double(n - 1))) / span[a];
    const int t1 = int(std::clamp(hi, 0.0, double(n - 1))) / span[a];
    tiles *= uint64_t(t1 - t0 + 1);
  }
  return std::min(tiles, all);
}

// Entries each thread buffers before a flush. A flush pulls each active
// 128 KiB tile (2048 cache lines) into L2 once, so more entries per tile
// mean more increments per line fetched: ~32768 per reachable tile on the
// fast path (4-byte entries, at most 2^26 = 256 MiB), ~8192 on the general
// path (8-byte keys, at most 2^25 = 256 MiB).
// Never more than the whole job plots; with a budget, at most an eighth of
// it per thread.
size_t BufferEntries(const ChaosGameParams& p, uint64_t reachable_tiles) {
  const bool fast = ChaosGame::UsesFastPath(p);
  const uint64_t per_tile = fast ? 32768 : 8192;
  const uint64_t entry_bytes = fast ? sizeof(uint32_t) : kKeyBytes;
  const uint64_t most = fast ? uint64_t{1} << 26 : uint64_t{1} << 25;
  uint64_t want = std::min(reachable_tiles * per_tile, std::max<uint64_t>(p.iterations, 1));
  if (p.memory_budget > 0) want = std::min(want, p.memory_budget / 8 / entry_bytes);
  return size_t(std::clamp<uint64_t>(want, uint64_t{1} << 16, most));
}

// The tiles the fast path's bin pool is sized for. A pool for every
// reachable tile while the attractor touches a few of them only streams
// through memory between flushes (a 256^3 Sierpinski tetrahedron reaches
// 512 tiles and touches about 100), so long runs size it by a short pilot's
// census instead. Results do not depend on the pool, only speed does.
uint64_t PoolTiles(const ChaosGameParams& p, bool fast) {
  constexpr uint64_t kPilotPoints = uint64_t{1} << 18;
  const uint64_t reachable = ReachableTiles(p);
  // Pilots run far fewer points than this, so they never pilot themselves.
  if (!fast || p.image || p.iterations < 64 * kPilotPoints) return reachable;
  auto census = ChaosGame::Pilot(p, kPilotPoints, nullptr);
  if (!census.ok() || census->estimate == 0) return reachable;
  return std::min(reachable, census->estimate);
}

// Most tiles a run incrementing at once may touch (32 MiB of counters): the
// only fast-path runs on several threads that keep one grid per thread.
constexpr uint64_t kDirectTiles = 256;

// Whether the fast path increments voxels at once (TileBins' direct mode)
// rather than binning them: when the attractor's hot counters fit in the
// caches, binning only adds a write and a read of every point. Hot bytes
// are estimated by a pilot census of 8^3 bricks (2 KiB of counters each;
// 8 x 8 x 1 on a thin grid), run only when few tiles are touched; short
// jobs and pictures go by the tiles alone. Counts do not depend on the
// choice, only speed does (bench/chaos_game_bench.cc, BM_FastPathSink).
bool DirectIncrements(const ChaosGameParams& p, uint64_t pool_tiles) {
  constexpr uint64_t kDirectBytes = uint64_t{4} << 20;  // hot counters
  constexpr uint64_t kPilotPoints = uint64_t{1} << 18;
  if (p.direct_increments) return *p.direct_increments;
  if (pool_tiles > kDirectTiles) return false;
  if (p.image || p.iterations < 64 * kPilotPoints) return true;
  const Int3 r = p.frame.resolution;
  const Int3 brick{std::min(r.x, 8), std::min(r.y, 8), std::min(r.z, 8)};
  auto census = ChaosGame::Pilot(p, kPilotPoints, nullptr, brick);
  if (!census.ok()) return false;
  const uint64_t brick_bytes = uint64_t(brick.x) * brick.y * brick.z * sizeof(uint32_t);
  return census->estimate * brick_bytes <= kDirectBytes;
}

// Where a plotted point lands, as both walk kernels take it: voxel
// coordinates (q - min) * inv_voxel, inside `res`, stored in `grid`'s
// layout. A picture's lattice is (width, height, 1), its rows folded as
// ImagePlane::Voxel folds them into the depth of an unfolded grid.
struct GridMapping {
  double min[3], inv_voxel[3];
  Int3 res;
  uint32_t fold_shift, fold_mask, tiles_y, tiles_z;
};

GridMapping MappingFor(const ChaosGameParams& p, const CountGrid& grid) {
  GridMapping m;
  const Vec3 vs = p.frame.VoxelSize();
  for (int a = 0; a < 3; ++a) m.min[a] = p.frame.bounds.min[a], m.inv_voxel[a] = 1.0 / vs[a];
  m.res = p.image ? Int3{p.image->width, p.image->height, 1} : p.frame.resolution;
  m.fold_shift = p.image ? ImagePlane::kFoldShift : grid.fold_shift();
  m.fold_mask = p.image ? ImagePlane::kFoldMask : grid.fold_mask();
  m.tiles_y = uint32_t(grid.tiles().y), m.tiles_z = uint32_t(grid.tiles().z);
  return m;
}

}  // namespace

flame::PlotTarget MakePlotTarget(const ChaosGameParams& p, const CountGrid& grid) {
  flame::PlotTarget t;
  const GridMapping m = MappingFor(p, grid);
  for (int a = 0; a < 3; ++a) t.min[a] = m.min[a], t.inv_voxel[a] = m.inv_voxel[a];
  t.res[0] = m.res.x, t.res[1] = m.res.y, t.res[2] = m.res.z;
  t.fold_shift = m.fold_shift, t.fold_mask = m.fold_mask;
  t.tiles_y = m.tiles_y, t.tiles_z = m.tiles_z;
  if (const ImagePlane* image = p.image ? &*p.image : nullptr) {
    t.kind = image->perspective ? flame::PlotTarget::kPerspective : flame::PlotTarget::kOrtho;
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 4; ++c) t.view[4 * r + c] = image->view.m[r][c];
    t.focal = image->focal, t.cx = image->cx, t.cy = image->cy, t.near = image->near;
    const double* v = t.view;
    t.axis_aligned = t.kind == flame::PlotTarget::kOrtho && v[1] == 0 && v[2] == 0 && v[4] == 0 &&
                     v[6] == 0 && v[8] == 0 && v[9] == 0;
  }
  t.color = p.color.mode != ColorMode::kNone;
  return t;
}

bool ChaosGame::UsesFastPath(const ChaosGameParams& p) {
  return !p.ifs.final_map && !p.ifs.arcs && !p.splat && p.color.mode == ColorMode::kNone &&
         p.ifs.AllAffine() && !(p.image && p.image->perspective);
}

ChaosGameMemory ChaosGame::EstimateMemory(const ChaosGameParams& p, int threads,
                                          uint64_t output_bytes_per_voxel, uint64_t tiles_hint) {
  threads = std::max(1, threads);
  const Int3 r = p.CountResolution();
  const bool color = p.color.mode != ColorMode::kNone;
  const uint64_t reachable = ReachableTiles(p);
  const uint64_t tiles = tiles_hint > 0 ? std::min(reachable, tiles_hint) : reachable;
  // Every plotted step lands in at most one tile of one thread, so the
  // tiles of all threads together are bounded by the iterations as well as
  // by threads x the reachable tiles.
  const uint64_t touches = (p.iterations + uint64_t(threads) * kWalkers) * (p.splat ? 8 : 1);
  // Binned fast-path runs share one grid between their threads; the engine
  // gives a grid per thread only to runs it finds on at most kDirectTiles
  // tiles, so with sharing each further thread adds at most that many.
  const bool shared = UsesFastPath(p) && threads > 1 && p.shared_grid.value_or(true) &&
                      !p.direct_increments.value_or(false);
  const uint64_t others = uint64_t(threads - 1) * std::min(tiles, kDirectTiles);
  const uint64_t all_tiles = std::min(
      shared ? tiles + others : SharesPackedGrid(p, threads) ? tiles : tiles * uint64_t(threads),
      touches);
  ChaosGameMemory m;
  // The buffers are sized by the geometric bound, as Create sizes them.
  const size_t entries = BufferEntries(p, reachable);
  const uint64_t buffers =
      UsesFastPath(p) ? TileBins::Bytes(r, entries) : KeyBins::Bytes(r, entries, color);
  m.accumulation = uint64_t(threads) * CountGrid::BoundedMemoryBytes(r, 0, color) +
                   all_tiles * CountGrid::TileBytes(color) + uint64_t(threads) * buffers;
  // Output: the merged grid, plus one VDB leaf (8^3 voxels, with ~15 %
  // tree overhead) per touched leaf: 64 per tile, 512 per folded tile.
  const uint64_t merged = CountGrid::BoundedMemoryBytes(r, std::min(tiles, touches), color);
  const uint64_t leaves = std::min(tiles * CountGrid::LeavesPerTile(r), touches);
  m.output = merged + leaves * 512 * output_bytes_per_voxel * 115 / 100;
  return m;
}

absl::StatusOr<TileCensus> ChaosGame::Pilot(const ChaosGameParams& params, uint64_t samples,
                                            Interrupter* interrupter, Int3 cell) {
  ChaosGameParams p = params;
  p.image.reset();  // a census of the volume grid's tiles
  p.direct_increments.reset();
  const Int3 r = params.frame.resolution;
  const Vec3 vs = params.frame.VoxelSize();
  // Voxels of the real grid per tile (or cell).
  const Int3 span = cell.x > 0 ? cell : CountGrid::TileSpan(r);
  p.frame.resolution = {(r.x + span.x - 1) / span.x, (r.y + span.y - 1) / span.y,
                        (r.z + span.z - 1) / span.z};
  // Pilot voxel i covers exactly tile i of the real grid.
  for (int a = 0; a < 3; ++a)
    p.frame.bounds.max[a] = p.frame.bounds.min[a] + p.frame.resolution[a] * span[a] * vs[a];
  p.iterations = std::max<uint64_t>(1, std::min(samples, params.iterations));
  p.color = {};
  p.splat = false;
  p.convergence = {};
  p.memory_budget = 0;
  p.chunk_begin = p.chunk_end = 0;
  auto game = Create(p, 1);
  if (!game.ok()) return game.status();
  if (auto st = (*game)->Run(interrupter); !st.ok()) return st;
  const CountGrid counts = (*game)->TakeCounts();
  const Int3 pr = p.frame.resolution;
  TileCensus c;
  c.samples = p.iterations;
  std::vector<uint8_t> hit(size_t(pr.x) * pr.y * pr.z, 0);
  counts.ForEachVoxel([&](Int3 v, uint32_t n) {
    if (v.x >= pr.x || v.y >= pr.y || v.z >= pr.z) return;
    hit[(size_t(v.x) * pr.y + v.y) * pr.z + v.z] = 1;
    ++c.seen;
    c.singletons += n == 1;
    c.doubletons += n == 2;
  });
  const double f1 = double(c.singletons), f2 = double(c.doubletons);
  const double unseen = f2 > 0 ? f1 * f1 / (2 * f2) : f1 * (f1 - 1) / 2;
  double factor = 1.25;
  if (params.splat && c.seen > 0) {
    // A splatted point reaches at most one voxel into the next tile: count
    // the tiles within one of a tile seen.
    uint64_t grown = 0;
    for (int x = 0; x < pr.x; ++x)
      for (int y = 0; y < pr.y; ++y)
        for (int z = 0; z < pr.z; ++z) {
          bool near = false;
          for (int dx = -1; dx <= 1 && !near; ++dx)
            for (int dy = -1; dy <= 1 && !near; ++dy)
              for (int dz = -1; dz <= 1 && !near; ++dz) {
                const int X = x + dx, Y = y + dy, Z = z + dz;
                near = X >= 0 && Y >= 0 && Z >= 0 && X < pr.x && Y < pr.y && Z < pr.z &&
                       hit[(size_t(X) * pr.y + Y) * pr.z + Z];
              }
          grown += near;
        }
    factor *= double(grown) / double(c.seen);
  }
  c.estimate = uint64_t(std::ceil((double(c.seen) + unseen) * factor)) + 8;
  return c;
}

uint64_t ChaosGame::MemoryBytes() const {
  uint64_t bytes = 0;
  for (const CountGrid& g : counts_) bytes += g.MemoryBytes();
  for (const auto& w : workers_) {
    if (w->keys) bytes += w->keys->MemoryBytes();
    if (w->bins) bytes += w->bins->MemoryBytes();
  }
  return bytes;
}

ChaosGameStats ChaosGame::stats() const {
  ChaosGameStats s;
  for (const auto& w : workers_) {
    s.iterations_done += w->stats.iterations_done;
    s.outside += w->stats.outside;
    s.reseeded += w->stats.reseeded;
    s.final_nonfinite += w->stats.final_nonfinite;
  }
  return s;
}

bool ChaosGame::Stopping(uint64_t chunk) {
  if (!poll_stop_) return false;
  if (poll_stop_->load(std::memory_order_relaxed)) return true;
  if (!OrNull(poll_intr_).WasInterrupted((chunk - begin_chunk_) * kChunkIterations,
                                         range_iterations()))
    return false;
  poll_stop_->store(true, std::memory_order_relaxed);
  return true;
}

// Counts steps and polls every kPollSteps; once stopped, stays stopped.
struct ChaosGame::Poll {
  ChaosGame* game;
  uint64_t chunk;
  uint64_t left = kPollSteps;
  bool stopped = false;
  bool Tick() {
    if (--left > 0) [[likely]]
      return stopped;
    left = kPollSteps;
    return stopped = stopped || game->Stopping(chunk);
  }
  // `steps` steps at once.
  bool Tick(uint64_t steps) {
    if (left > steps) [[likely]] {
      left -= steps;
      return stopped;
    }
    left = kPollSteps;
    return stopped = stopped || game->Stopping(chunk);
  }
};

// One fast-path chunk: the walkers, the kernel's view of the job and the
// callbacks it makes for the rare cases (a full bin, a point off the grid).
struct ChaosGame::FastChunk {
  walk::Walkers lanes;
  walk::AffineWalk kernel;
  TileBins* bins = nullptr;
  const ChaosGameParams* p = nullptr;
  const AliasTable* table = nullptr;
  const std::vector<AliasTable>* state_tables = nullptr;  // with a chain
  const std::vector<Affine3>* maps = nullptr;             // ChaosGame::fast_maps_
  uint64_t outside = 0, reseeded = 0;
  Poll* poll = nullptr;

  Rng LoadRng(int l) const {
    return Rng::FromState(lanes.s0[l], lanes.s1[l], lanes.s2[l], lanes.s3[l]);
  }
  void Store(int l, const Rng& rng, Vec3 pos) {
    lanes.s0[l] = rng.state(0), lanes.s1[l] = rng.state(1);
    lanes.s2[l] = rng.state(2), lanes.s3[l] = rng.state(3);
    lanes.x[l] = pos.x, lanes.y[l] = pos.y, lanes.z[l] = pos.z;
  }
  // RunChunk's warm_up for this case, draw for draw.
  Vec3 Start(Rng& rng) const {
    const Vec3 q = RandomPoint(rng, p->frame.bounds);
    return p->image ? p->image->view.Apply(q) : q;
  }
  void WarmUp(int l) {
    Rng rng = LoadRng(l);
    Vec3 pos = Start(rng);
    const MarkovChain* chain = p->chain ? &*p->chain : nullptr;
    uint32_t state = chain ? chain->start_state : 0;
    for (uint32_t i = 0; i < p->warmup; ++i) {
      // A stopped chunk's counts are thrown away: leave the walker as is.
      if (poll->Tick()) [[unlikely]]
        break;
      uint32_t map;
      if (chain) {
        const ChainTransition& t =
            chain->states[state].transitions[(*state_tables)[state].Sample(rng.Next())];
        map = t.map;
        state = t.next_state;
      } else {
        map = table->Sample(rng.Next());
      }
      pos = (*maps)[map].Apply(pos);
      if (!IsFinite(pos)) {
        pos = Start(rng);
        ++reseeded;
      }
    }
    Store(l, rng, pos);
    lanes.state[l] = state;
  }
  static void Refill(void* self, uint32_t bin) { static_cast<FastChunk*>(self)->bins->Refill(bin); }
  static uint32_t* Allocate(void* self, uint32_t tile) {
    return static_cast<FastChunk*>(self)->bins->Allocate(tile);
  }
  // RunChunk's advance: a non-finite point restarts the walker, a finite
  // one off the grid is counted.
  static void Exit(void* self, int l) {
    auto* c = static_cast<FastChunk*>(self);
    if (IsFinite(Vec3{c->lanes.x[l], c->lanes.y[l], c->lanes.z[l]})) {
      ++c->outside;
    } else {
      ++c->reseeded;
      c->WarmUp(l);
    }
  }
};

void ChaosGame::RunChunkFast(uint64_t chunk, Worker& w) {
  const ChaosGameParams& p = params_;
  const uint64_t begin = chunk * kChunkIterations;
  const uint64_t count = std::min(kChunkIterations, p.iterations - begin);
  FastChunk c;
  Poll poll{this, chunk};
  c.poll = &poll;
  c.bins = w.bins.get();
  c.p = &p;
  c.table = &map_table_;
  c.state_tables = &state_tables_;
  c.maps = &fast_maps_;
  for (int l = 0; l < kWalkers; ++l) {
    c.Store(l, Rng(p.seed, chunk * kWalkers + uint64_t(l)), {});
    c.WarmUp(l);
  }
  walk::AffineWalk& k = c.kernel;
  k.coef = affine_coef_.data();
  k.threshold = map_table_.thresholds();
  k.alias = map_table_.aliases();
  k.num_maps = uint32_t(p.ifs.maps.size());
  k.planar = planar_ && !flat_chain_;
  walk::ChainTables chain;
  if (flat_chain_) {
    const FlatChain& f = *flat_chain_;
    chain = {f.state.data(), f.sample.data(), f.step.data()};
    k.chain = &chain;
  }
  const GridMapping m = MappingFor(p, *w.grid);
  // A picture's points are walked already projected to pixels.
  for (int a = 0; a < 3; ++a) {
    k.min[a] = p.image ? 0.0 : m.min[a];
    k.inv_voxel[a] = p.image ? 1.0 : m.inv_voxel[a];
  }
  k.res[0] = m.res.x, k.res[1] = m.res.y, k.res[2] = m.res.z;
  k.fold_mask = m.fold_mask, k.fold_shift = m.fold_shift;
  k.tiles_y = m.tiles_y, k.tiles_z = m.tiles_z;
  k.bin_shift = c.bins->bin_shift();
  k.bins = c.bins->cursors();
  k.owner = &c;
  k.refill = &FastChunk::Refill;
  k.tiles = c.bins->tiles();
  k.flat = c.bins->flat();
  k.flat_stride[0] = uint32_t(m.res.y), k.flat_stride[1] = uint32_t(m.res.z);
  k.flat_discard = c.bins->flat_discard();
  k.allocate = &FastChunk::Allocate;
  k.exit = &FastChunk::Exit;

  const uint64_t rounds = count / kWalkers;
  if (simd_ == SimdLevel::kAvx512)
    walk::WalkAvx512(k, c.lanes, rounds);
  else if (simd_ == SimdLevel::kAvx2)
    walk::WalkAvx2(k, c.lanes, rounds);
  else
    walk::WalkScalar(k, c.lanes, rounds);
  for (int l = 0; l < int(count % kWalkers); ++l) walk::WalkLane(k, c.lanes, l, 1);
  w.stats.outside += c.outside;
  w.stats.reseeded += c.reseeded;
  w.stats.iterations_done += count;
}

namespace {

// A walker's colour coordinate as the key bits of one visit.
inline uint64_t ColorBits(double col) {
  const double c = std::clamp(col, 0.0, 1.0);
  return CountGrid::WithColor(0, uint32_t(c * CountGrid::kColorScale + 0.5));
}

// Trilinear splatting of one point at fractional voxel coordinates (fx, fy,
// fz): voxel centres sit at i + 0.5, so the point lies between centres i0
// and i0 + 1 on each axis, at quarter q (0..4) of the way. Corners outside
// the grid fold onto the border voxel so every point adds exactly 64.
// Writes at most 8 keys; returns how many.
size_t AppendSplatKeys(const CountGrid& grid, Int3 res, double fx, double fy, double fz,
                       uint64_t color_bits, uint64_t* keys) {
  int i0[3], quarter[3];
  const double f[3] = {fx - 0.5, fy - 0.5, fz - 0.5};
  for (int a = 0; a < 3; ++a) {
    const double fl = std::floor(f[a]);
    i0[a] = int(fl);
    quarter[a] = int(std::lround((f[a] - fl) * 4));
  }
  const int lim[3] = {res.x - 1, res.y - 1, res.z - 1};
  size_t n = 0;
  for (int c = 0; c < 8; ++c) {
    uint32_t weight = 1;
    int v[3];
    for (int a = 0; a < 3; ++a) {
      const int hi = (c >> a) & 1;
      weight *= uint32_t(hi ? quarter[a] : 4 - quarter[a]);
      v[a] = std::clamp(i0[a] + hi, 0, lim[a]);
    }
    if (weight == 0) continue;
    keys[n++] = CountGrid::WithWeight(grid.Key(v[0], v[1], v[2]), weight) | color_bits;
  }
  return n;
}

}  // namespace

// The general path's walkers and what they share: one walker's step and
// warm-up, and the plotting of a point, for the walker-at-a-time loop
// (RunChunk, chains) and the batched one (RunChunkBatch) alike.
struct ChaosGame::General {
  struct Lane {
    Rng rng;
    Vec3 pos;
    uint32_t state = 0;
    double addr = 0, col = 0;
  };

  ChaosGame& game;
  Worker& w;
  const ChaosGameParams& p = game.params_;
  const Bounds& b = p.frame.bounds;
  const ImagePlane* image = p.image ? &*p.image : nullptr;
  const Int3 res = image ? Int3{image->width, image->height, 1} : p.frame.resolution;
  const Vec3 inv = {1.0 / p.frame.VoxelSize().x, 1.0 / p.frame.VoxelSize().y,
                    1.0 / p.frame.VoxelSize().z};
  const std::vector<PointMap>& maps = p.ifs.maps;
  const PointMap* final_map = p.ifs.final_map ? &*p.ifs.final_map : nullptr;
  const ArcsTransform* arcs = p.ifs.arcs ? &*p.ifs.arcs : nullptr;
  const MarkovChain* chain = p.chain ? &*p.chain : nullptr;
  const bool affine = p.ifs.AllAffine();
  const ColorMode color_mode = p.color.mode;
  const double blend = p.color.blend;
  const double inv_maps = 1.0 / double(maps.size());
  Poll poll;
  // Counters in locals: stores through `w` could alias them and would keep
  // them in memory.
  uint64_t reseeded = 0, outside = 0, final_nonfinite = 0;
  KeyBins& keys = *w.keys;

  const uint64_t steps;  // plotted steps of the chunk

  General(ChaosGame& g, Worker& worker, uint64_t chunk, uint64_t count)
      : game(g), w(worker), poll{&g, chunk}, steps(count) {}
  ~General() {
    w.stats.iterations_done += steps;
    w.stats.reseeded += reseeded;
    w.stats.outside += outside;
    w.stats.final_nonfinite += final_nonfinite;
  }

  uint32_t PickMap(Lane& l) {
    if (!chain) return game.map_table_.Sample(l.rng.Next());
    const ChainState& st = chain->states[l.state];
    const ChainTransition& t = st.transitions[game.state_tables_[l.state].Sample(l.rng.Next())];
    l.state = t.next_state;
    return t.map;
  }
  void Recolor(Lane& l, uint32_t map) {
    if (color_mode == ColorMode::kNone) return;
    l.addr = (double(map) + l.addr) * inv_maps;
    const double target = color_mode == ColorMode::kAddress ? l.addr : maps[map].color;
    l.col += blend * (target - l.col);
  }
  // One step; returns false if the point went non-finite.
  bool Step(Lane& l) {
    const uint32_t map = PickMap(l);
    l.pos = affine ? maps[map].pre.Apply(l.pos) : maps[map].Apply(l.pos, l.rng);
    Recolor(l, map);
    return IsFinite(l.pos);
  }
  void WarmUp(Lane& l) {
    l.pos = RandomPoint(l.rng, b);
    l.state = chain ? chain->start_state : 0;
    if (color_mode != ColorMode::kNone) l.addr = l.col = l.rng.Uniform();
    for (uint32_t i = 0; i < p.warmup; ++i) {
      if (poll.Tick()) [[unlikely]]
        return;
      if (!Step(l)) {
        l.pos = RandomPoint(l.rng, b);
        ++reseeded;
      }
    }
  }
  // Counts a plotted point `q` (after the final transform, when finite) of
  // the lane with colour `col`; `n` is the step's global index (the arcs'
  // phase).
  void Plot(Vec3 q, double col, uint64_t n) {
    if (arcs) q = arcs->Apply(q, n);
    if (!IsFinite(q)) {
      ++final_nonfinite;
      ++outside;
      return;
    }
    double fx = (q.x - b.min.x) * inv.x, fy = (q.y - b.min.y) * inv.y,
           fz = (q.z - b.min.z) * inv.z;
    if (image) {
      fz = 0;
      if (!image->Project(q, &fx, &fy)) fx = -1;  // off the picture
    }
    // Written so NaN fails the test and counts as outside.
    if (!(fx >= 0 && fx < res.x && fy >= 0 && fy < res.y && fz >= 0 && fz < res.z)) {
      ++outside;
      return;
    }
    const uint64_t color_bits = color_mode == ColorMode::kNone ? 0 : ColorBits(col);
    if (image) {
      const Int3 v = ImagePlane::Voxel(int(fx), int(fy));
      keys.Add(w.grid->Key(v.x, v.y, v.z) | color_bits);
      return;
    }
    if (!p.splat) {
      keys.Add(w.grid->Key(int(fx), int(fy), int(fz)) | color_bits);
      return;
    }
    uint64_t splat[8];
    const size_t corners = AppendSplatKeys(*w.grid, res, fx, fy, fz, color_bits, splat);
    for (size_t i = 0; i < corners; ++i) keys.Add(splat[i]);
  }
};

void ChaosGame::RunChunks(uint64_t first, uint64_t chunks, Worker& w) {
  if (!fast_ && !params_.chain) return RunChunkBatch(first, chunks, w);
  for (uint64_t c = first; c < first + chunks; ++c) RunChunk(c, w);
}

uint64_t ChaosGame::BatchChunks() const {
  return fast_ || params_.chain ? 1 : uint64_t(flame::kMaxWalkers / flame_walkers_);
}

// Whole blocks while every thread has two blocks' worth left, then smaller
// ones down to single chunks, so no thread is left with a long block as
// the others finish.
uint64_t ChaosGame::ChunksToTake(uint64_t next, uint64_t target) const {
  const uint64_t left = target - next;
  return std::clamp<uint64_t>(left / (2 * uint64_t(threads_)), 1, BatchChunks());
}

void ChaosGame::RunChunk(uint64_t chunk, Worker& w) {
  if (fast_) return RunChunkFast(chunk, w);
  const uint64_t begin = chunk * kChunkIterations;
  const uint64_t count = std::min(kChunkIterations, params_.iterations - begin);
  General g(*this, w, chunk, count);
  // Walker-major: each walker runs all its steps in turn with its generator
  // and position in registers. A walker's steps depend on each other only
  // through the position, which out-of-order execution overlaps.
  for (int k = 0; k < kWalkers; ++k) {
    General::Lane l;
    l.rng = Rng(params_.seed, chunk * kWalkers + uint64_t(k));
    g.WarmUp(l);
    // Walker k plots steps k, k + kWalkers, ... of the chunk.
    const uint64_t steps = count / kWalkers + (uint64_t(k) < count % kWalkers ? 1 : 0);
    for (uint64_t j = 0; j < steps; ++j) {
      // A stopped chunk's counts are thrown away with the job.
      if (g.poll.Tick()) [[unlikely]]
        break;
      if (!g.Step(l)) [[unlikely]] {
        ++g.reseeded;
        g.WarmUp(l);
        continue;
      }
      if (g.chain && !g.chain->states[l.state].plotted) continue;
      Vec3 q = l.pos;
      if (g.final_map) q = g.final_map->Apply(q, l.rng);
      g.Plot(q, l.col, begin + j * kWalkers + uint64_t(k));
    }
  }
}

// The general path without a chain: all walkers of the chunks step
// together, one round of the flame kernel of the SIMD level per step
// (core/chaos/flame_walk.h): each walker draws its step's words from its
// own stream, so any kernel takes it along the path the scalar one does,
// up to the rounding of the elementary functions. The chunks' walkers sit
// side by side in one block; only the run's last chunk can be short, and
// it comes last, so the walkers that plot in a round are a prefix.
void ChaosGame::RunChunkBatch(uint64_t first, uint64_t chunks, Worker& w) {
  const ChaosGameParams& p = params_;
  const uint64_t begin = first * kChunkIterations;
  const uint64_t count = std::min(chunks * kChunkIterations, p.iterations - begin);
  General g(*this, w, first, count);
  const flame::Program& prog = program_.program();
  const flame::RoundFn round = flame_round_;
  const int per = flame_walkers_;  // walkers per chunk
  const int n = per * int(chunks);
  const bool color = p.color.mode != ColorMode::kNone;
  // The chunks' walkers, and a block that re-warms one walker alone, copied
  // into every lane: lanes compute independently, so alone or in the batch
  // a walker takes the same path.
  auto blocks = std::make_unique<flame::Walkers[]>(2);
  flame::Walkers& s = blocks[0];
  flame::Walkers& solo = blocks[1];
  const size_t words = size_t(prog.words) * flame::kMaxWalkers;
  const size_t groups = size_t(prog.maps.num_maps) + 1;
  // Cache-line aligned: the kernels store and load whole 64-byte registers
  // of words, and malloc's 16-byte alignment would split most of them
  // across two lines.
  std::vector<uint64_t> word_buffer(2 * words + 7);
  std::vector<uint32_t> group_buffer(2 * groups);
  s.words = AlignedTo64(word_buffer.data()), solo.words = s.words + words;
  s.group = group_buffer.data(), solo.group = s.group + groups;
  auto rng_of = [](const flame::Walkers& b, int k) {
    return Rng::FromState(b.s0[k], b.s1[k], b.s2[k], b.s3[k]);
  };
  auto set_rng = [](flame::Walkers& b, int k, const Rng& r) {
    b.s0[k] = r.state(0), b.s1[k] = r.state(1), b.s2[k] = r.state(2), b.s3[k] = r.state(3);
  };
  auto reseed = [&](flame::Walkers& b, int k) {  // RandomPoint from the walker's stream
    Rng r = rng_of(b, k);
    const Vec3 q = RandomPoint(r, g.b);
    b.x[k] = q.x, b.y[k] = q.y, b.z[k] = q.z;
    set_rng(b, k, r);
  };
  auto restart = [&](flame::Walkers& b, int k) {  // General::WarmUp's start
    reseed(b, k);
    if (!color) return;
    Rng r = rng_of(b, k);
    b.addr[k] = b.col[k] = r.Uniform();
    set_rng(b, k, r);
  };
  auto finite = [](const flame::Walkers& b, int k) {
    return IsFinite(Vec3{b.x[k], b.y[k], b.z[k]});
  };
  auto copy = [](const flame::Walkers& from, int i, flame::Walkers& to, int j) {
    to.x[j] = from.x[i], to.y[j] = from.y[i], to.z[j] = from.z[i];
    to.addr[j] = from.addr[i], to.col[j] = from.col[i];
    to.s0[j] = from.s0[i], to.s1[j] = from.s1[i], to.s2[j] = from.s2[i], to.s3[j] = from.s3[i];
  };
  // A walker whose point went non-finite starts again and warms up alone.
  auto rewarm = [&](int k) {
    restart(s, k);
    for (int l = 0; l < flame::kAlign; ++l) copy(s, k, solo, l);
    for (uint32_t i = 0; i < p.warmup; ++i) {
      if (g.poll.Tick()) [[unlikely]]
        break;
      round(prog, solo, flame::kAlign);
      if (finite(solo, 0)) [[likely]]
        continue;
      reseed(solo, 0);
      ++g.reseeded;
      for (int l = 1; l < flame::kAlign; ++l) copy(solo, 0, solo, l);
    }
    copy(solo, 0, s, k);
  };

  // Walker k of chunk c has stream c * per + k: walker k of the block.
  for (int k = 0; k < n; ++k) {
    set_rng(s, k, Rng(p.seed, first * uint64_t(per) + uint64_t(k)));
    restart(s, k);
  }
  // A stopped chunk's counts are thrown away with the job.
  for (uint32_t i = 0; i < p.warmup; ++i) {
    if (g.poll.Tick(uint64_t(n))) [[unlikely]]
      return;
    round(prog, s, n);
    for (int k = 0; k < n; ++k) {
      if (finite(s, k)) [[likely]]
        continue;
      reseed(s, k);
      ++g.reseeded;
    }
  }
  const bool final_map = prog.final_map.num_maps != 0;
  const double* px = final_map ? s.fx : s.x;
  const double* py = final_map ? s.fy : s.y;
  const double* pz = final_map ? s.fz : s.z;
  auto plotted = std::make_unique<flame::Plotted>();
  // The full chunks' rounds; the last chunk's walkers plot count_last
  // steps, the first count_last % per of them one more.
  const uint64_t full = chunks - 1, count_last = count - full * kChunkIterations;
  const uint64_t rounds =
      full ? kChunkIterations / uint64_t(per) : (count_last + uint64_t(per) - 1) / uint64_t(per);
  for (uint64_t j = 0; j < rounds; ++j) {
    const uint64_t last =
        std::min<uint64_t>(uint64_t(per), count_last - std::min(count_last, j * per));
    const int active = int(full * uint64_t(per) + last);
    if (g.poll.Tick(uint64_t(active))) [[unlikely]]
      break;
    round(prog, s, n);
    if (flame_plot_) {
      PlotRound(g, s, final_map, n, active, *plotted, rewarm);
      continue;
    }
    for (int k = 0; k < active; ++k) {
      if (!finite(s, k)) [[unlikely]] {
        ++g.reseeded;
        rewarm(k);
        continue;
      }
      // Walker k % per of chunk first + k / per, at its step j.
      const uint64_t step =
          uint64_t(k / per) * kChunkIterations + j * uint64_t(per) + uint64_t(k % per);
      g.Plot({px[k], py[k], pz[k]}, s.col[k], begin + step);
    }
  }
}

// One round's points through the plot kernel: keys of the lanes that land
// go to the bins, the rest are counted; walkers gone non-finite restart.
// Lanes are independent, so restarting them after the round's plot
// changes nothing the one-lane-at-a-time loop would have done.
template <typename Rewarm>
void ChaosGame::PlotRound(General& g, const flame::Walkers& s, bool final_map, int n, int active,
                          flame::Plotted& out, Rewarm& rewarm) {
  flame_plot_(plot_target_, s, final_map, n, &out);
  static_assert(flame::kMaskWords <= KeyBins::kMaxLaneWords);
  const int words = (active + 63) / 64;
  uint64_t inside[flame::kMaskWords], restarted = 0;
  for (int word = 0; word < words; ++word) {
    const int lanes = std::min(64, active - 64 * word);
    const uint64_t mask = lanes == 64 ? ~uint64_t{0} : (uint64_t{1} << lanes) - 1;
    inside[word] = out.inside[word] & mask;
    // Lanes counted by walking their bits: the x86-64 baseline has no popcnt.
    for (uint64_t m = out.bad_final[word] & mask; m; m &= m - 1) ++g.final_nonfinite;
    for (uint64_t m = out.bad_walker[word] & mask; m; m &= m - 1, ++restarted)
      rewarm(64 * word + std::countr_zero(m));
  }
  const uint64_t landed = g.keys.AddLanes(out.key, inside, words);
  g.reseeded += restarted;
  g.outside += uint64_t(active) - landed - restarted;
}

absl::Status ChaosGame::RunUntil(uint64_t iterations, Interrupter* interrupter) {
  Interrupter& intr = OrNull(interrupter);
  const uint64_t target = std::min(end_chunk_, begin_chunk_ + NumChunks(iterations));
  if (next_chunk_ >= target) return absl::OkStatus();
  std::atomic<uint64_t> next{next_chunk_};
  std::atomic<bool> stop{false}, over_budget{false};
  poll_intr_ = interrupter;
  poll_stop_ = &stop;
  const bool last_round = target == end_chunk_;
  auto body = [&](int t) {
    Worker& w = *workers_[t];
    while (!stop.load(std::memory_order_relaxed)) {
      uint64_t c = next.load(std::memory_order_relaxed), take = 0;
      do {
        if (c >= target) break;
        take = ChunksToTake(c, target);
      } while (!next.compare_exchange_weak(c, c + take, std::memory_order_relaxed));
      if (c >= target) break;
      RunChunks(c, take, w);
      if (w.overflowed()) over_budget = stop = true;
      const uint64_t last = c + take - 1;
      if (intr.WasInterrupted((last - begin_chunk_) * kChunkIterations, range_iterations()))
        stop = true;
    }
    // Threads sharing packed words' grid fold the last round together,
    // below; others fold their own.
    if ((last_round && !shared_keys_) || !w.DefersFlush()) w.Flush();
    if (w.overflowed()) over_budget = stop = true;
  };
  const int n = int(std::min<uint64_t>(threads_, target - next_chunk_));
  // One task per accumulator, run by the caller's task arena (a job's arena
  // is sized by --threads-per-job); no threads are created per round.
  tbb::task_group group;
  for (int t = 1; t < n; ++t) group.run([&body, t] { body(t); });
  body(0);
  group.wait();
  unfolded_ = unfolded_ || !last_round || shared_keys_;
  // A last round of fewer chunks than threads leaves out workers that may
  // still hold words from earlier rounds.
  if (last_round) FoldPending();
  for (const auto& w : workers_)
    if (w->overflowed()) over_budget = stop = true;
  poll_intr_ = nullptr;
  poll_stop_ = nullptr;
  if (over_budget)
    return absl::ResourceExhaustedError(absl::StrCat(
        "the chaos game's counters outgrew the memory budget of ", params_.memory_budget >> 20,
        " MiB (", threads_, " threads); the attractor covers more of the grid than estimated"));
  if (stop) return absl::CancelledError("interrupted");
  next_chunk_ = target;
  return absl::OkStatus();
}

void ChaosGame::FoldPending() {
  if (!unfolded_) return;
  unfolded_ = false;
  if (shared_keys_ && FoldSharedByTile()) return;
  // On the caller's thread; an outgrown budget shows in the next round
  // (Worker::overflowed).
  for (auto& w : workers_) w->Flush();
}

// The threads' packed words folded into the grid they share, tile by tile
// on all of the arena's threads: one thread folding everything under the
// fold lock, the others waiting, spent some 24 ms on the flame volume's
// last fold, most of it the first touch of the grid's fresh tiles. False
// (nothing folded) past the grid's tile limit, where tiles share a
// scratch tile and must fold one thread at a time.
bool ChaosGame::FoldSharedByTile() {
  uint64_t touched = 0;
  for (auto& w : workers_) touched |= w->keys->BeginFold();
  CountGrid& grid = counts_[0];
  std::vector<uint64_t> tiles;
  for (uint64_t m = touched; m; m &= m - 1) {
    tiles.push_back(uint64_t(std::countr_zero(m)));
    grid.MutableTile(tiles.back());  // allocated here: FoldTileOf only reads the table
  }
  if (grid.overflowed()) return false;
  tbb::parallel_for(size_t{0}, tiles.size(), [&](size_t i) {
    for (auto& w : workers_) w->keys->FoldTileOf(tiles[i]);  // worker order: fixed sums
  });
  for (auto& w : workers_) w->keys->EndFold();
  return true;
}

const std::vector<CountGrid>& ChaosGame::partial_counts() {
  FoldPending();
  return counts_;
}

std::vector<uint64_t> CoarseCounts(const std::vector<const CountGrid*>& parts, int max_resolution) {
  if (parts.empty()) return {};
  const Int3 r = parts[0]->resolution();
  // Whole tiles per cell keeps this a pass over tile sums.
  int cell = CountGrid::kTileDim;
  while ((std::max({r.x, r.y, r.z}) + cell - 1) / cell > max_resolution) cell *= 2;
  const Int3 c{(r.x + cell - 1) / cell, (r.y + cell - 1) / cell, (r.z + cell - 1) / cell};
  std::vector<uint64_t> out(size_t(c.x) * c.y * c.z, 0);
  for (const CountGrid* g : parts) {
    if (g->folded()) {
      // A folded tile spans more than one cell.
      g->ForEachVoxel([&](Int3 v, uint32_t n) {
        out[(size_t(v.x / cell) * c.y + v.y / cell) * c.z + v.z / cell] += n;
      });
      continue;
    }
    g->ForEachTile([&](Int3 o, const uint32_t* t) {
      uint64_t sum = 0;
      for (int i = 0; i < CountGrid::kTileVoxels; ++i) sum += t[i];
      out[(size_t(o.x / cell) * c.y + o.y / cell) * c.z + o.z / cell] += sum;
    });
  }
  return out;
}

double DensityChange(const std::vector<uint64_t>& a, const std::vector<uint64_t>& b) {
  if (a.size() != b.size()) return 2;
  uint64_t ta = 0, tb = 0;
  for (uint64_t v : a) ta += v;
  for (uint64_t v : b) tb += v;
  if (ta == 0 || tb == 0) return ta == tb ? 0 : 2;
  double d = 0;
  for (size_t i = 0; i < a.size(); ++i) d += std::fabs(double(a[i]) / ta - double(b[i]) / tb);
  return d;
}

std::pair<uint64_t, uint64_t> ChaosGame::ShardChunks(uint64_t iterations, uint32_t shards,
                                                     uint32_t index) {
  const unsigned __int128 n = NumChunks(iterations), s = std::max<uint32_t>(shards, 1);
  return {uint64_t(n * index / s), uint64_t(n * (index + 1) / s)};
}

uint64_t ChaosGame::range_iterations() const {
  const uint64_t end = std::min(params_.iterations, end_chunk_ * kChunkIterations);
  return end - begin_chunk_ * kChunkIterations;
}

CountGrid ChaosGame::TakeCounts() {
  FoldPending();     // a run stopped before its last round
  workers_.clear();  // the key buffers first: lowers the merge's peak
  shared_tiles_.reset();
  for (CountGrid& g : counts_) g.SetTileLimit(0);
  CountGrid out = std::move(counts_[0]);
  for (size_t t = 1; t < counts_.size(); ++t) {
    out.Merge(counts_[t]);
    counts_[t] = CountGrid(params_.CountResolution());  // release memory early
  }
  counts_.clear();
  workers_.clear();
  return out;
}

}  // namespace nimbus
