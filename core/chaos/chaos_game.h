// The 3D chaos game (random iteration) for point IFS and graph-directed
// (recurrent) IFS, accumulating integer visit counts.
#pragma once

#include <atomic>
#include <cstdint>
#include <mutex>
#include <optional>
#include <utility>
#include <vector>

#include "absl/status/statusor.h"
#include "core/grid/count_grid.h"
#include "core/base/cpu_dispatch.h"
#include "core/base/geometry.h"
#include "core/base/interrupter.h"
#include "core/chaos/flame_program.h"
#include "core/chaos/image_plane.h"
#include "core/chaos/point_map.h"

namespace nimbus {

class SharedTiles;

/// One edge of a recurrent IFS seen as a Markov chain: apply `map` (an index
/// into Ifs::maps) and move to `next_state`.
struct ChainTransition {
  uint32_t map = 0;
  uint32_t next_state = 0;
};

/// A state of the chain. Points produced while the walker is in a state are
/// plotted only if `plotted`; `label` tags them for a component grid.
struct ChainState {
  std::vector<ChainTransition> transitions;  // must be non-empty
  std::vector<double> probabilities;         // one per transition, sum 1
  bool plotted = true;
  int32_t label = 0;
};

/// @brief A graph-directed IFS as a Markov chain over states. A plain IFS is
/// the one-state chain whose transitions are its maps.
struct MarkovChain {
  std::vector<ChainState> states;
  uint32_t start_state = 0;
};

}  // namespace nimbus

namespace nimbus {

/// Where a walker's colour coordinate comes from (docs/chaos_game.md).
enum class ColorMode {
  kNone,     // no colour accumulated
  kAddress,  // the point's address addr <- (i + addr) / N, blended
  kMap,      // the colour index of the map just applied (flame-style), blended
};

/// @brief Per-walker colour: c <- (1 - blend) c + blend * new, where `new` is
/// the address or the map's colour index. Each visit adds c (16-bit fixed
/// point) to its voxel's colour sum; the output colour is the palette at the
/// voxel's mean c.
struct ColorParams {
  ColorMode mode = ColorMode::kNone;
  double blend = 0.05;  // weight of the new value, in (0, 1]
};

/// @brief Optional early stop: the runner compares normalised coarse
/// densities at fixed checkpoints (every `check_every` plotted steps, whole
/// chunks) and stops when their L1 distance is below `tolerance`. Fixed
/// checkpoints keep the stopping point independent of threads and timing.
struct ConvergenceParams {
  double tolerance = 0;  // 0: off
  uint64_t check_every = uint64_t{1} << 26;
};

/// L1 distance between the normalised densities of two count sets, each
/// summed over its parts and downsampled to at most `max_resolution` per
/// axis; in [0, 2]. Deterministic.
double DensityChange(const std::vector<uint64_t>& a, const std::vector<uint64_t>& b);
/// Coarse totals of `parts` for DensityChange: cells of at most
/// `max_resolution` per axis, x slowest.
std::vector<uint64_t> CoarseCounts(const std::vector<const CountGrid*>& parts, int max_resolution);

/// What to iterate and where to count it.
struct ChaosGameParams {
  Ifs ifs;
  /// When set, the walk follows this chain over ifs.maps instead of drawing
  /// maps independently with ifs.probabilities.
  std::optional<MarkovChain> chain;
  GridFrame frame;
  /// Plotted steps in total, over all walkers (warm-up not included).
  uint64_t iterations = 0;
  /// Unplotted steps each walker takes first, and again after a re-seed.
  uint32_t warmup = 100;
  uint64_t seed = 0;
  ColorParams color;
  ConvergenceParams convergence;
  /// Trilinear splatting: each plotted point spreads over the 8 voxels
  /// whose centres surround it, with per-axis weights quantised to quarters,
  /// so counts are in units of 1/kSplatScale visit.
  bool splat = false;
  /// SIMD level of the walk kernels; unset means ActiveSimd(). Never above
  /// what the CPU has. Affine maps count the same at every level; maps with
  /// variations count the same for a given level (docs/chaos_game.md).
  std::optional<SimdLevel> simd;
  /// Whether the fast path increments voxels as it goes (true) or bins
  /// them by tile first (false); unset lets the engine choose by the tiles
  /// the attractor touches. Counts are the same either way: for tests and
  /// benchmarks.
  std::optional<bool> direct_increments;
  /// Whether the binned fast path's threads (SharedTiles), and the general
  /// path's threads when their keys are packed (KeyBins::Packs), fill one
  /// shared grid (true) or one grid each, merged at the end (false); unset
  /// shares whenever there is more than one thread. Counts are the same
  /// either way: for tests and benchmarks.
  std::optional<bool> shared_grid;
  /// Bytes the accumulation may hold (0: no limit). A run whose counters
  /// outgrow it stops with ResourceExhausted instead of exhausting the
  /// machine: the safety net behind EstimateMemory.
  uint64_t memory_budget = 0;
  /// Run only the chunks [chunk_begin, chunk_end) of the whole run of
  /// `iterations` (a shard, docs/sharding.md); chunk_end 0 means to the end.
  /// Chunks draw their own random streams, so the counts of ranges that
  /// tile the run add up to the full run's counts exactly.
  uint64_t chunk_begin = 0;
  uint64_t chunk_end = 0;
  /// When set, points are counted on this image's pixels instead of the
  /// voxels of `frame` (which still gives the walkers' starting box); the
  /// counts come in ImagePlane's folded layout. Not with splat.
  std::optional<ImagePlane> image;

  /// The resolution of the counters: the grid's, or the folded image's.
  Int3 CountResolution() const { return image ? image->folded_resolution() : frame.resolution; }
};

/// Count units per plotted point when splatting (4 x 4 x 4).
inline constexpr uint32_t kSplatScale = 64;

/// Counters a run reports; all exact and independent of the thread count.
struct ChaosGameStats {
  uint64_t iterations_done = 0;  // plotted-or-outside steps finished
  uint64_t outside = 0;          // steps whose point fell outside the grid bounds
  uint64_t reseeded = 0;         // walkers restarted after a non-finite point
  uint64_t final_nonfinite = 0;  // plotted points the final transform made non-finite
};

/// @brief What a pilot run saw of the tiles a job touches (ChaosGame::Pilot).
struct TileCensus {
  uint64_t samples = 0;     // plotted steps of the pilot
  uint64_t seen = 0;        // tiles hit at least once
  uint64_t singletons = 0;  // tiles hit exactly once
  uint64_t doubletons = 0;  // tiles hit exactly twice
  /// Tiles a full run is expected to touch: the tiles seen plus the Chao1
  /// estimate of tiles the pilot missed (singletons^2 / (2 doubletons)),
  /// with a 25 % margin, grown by one tile around each when splatting.
  uint64_t estimate = 0;
};

/// @brief Honest memory bounds of a chaos-game job, in bytes. Each plotted
/// step touches one tile, so allocated tiles are bounded by both the grid
/// and the number of iterations.
struct ChaosGameMemory {
  uint64_t accumulation = 0;  // all threads' counters and key buffers
  uint64_t output = 0;        // merged counters plus the output VDB grids
  uint64_t peak() const { return accumulation > output ? accumulation : output; }
};

/// @brief The chaos game, split into fixed chunks of work so that any number
/// of threads produce the same counts: chunk c always runs the same walkers
/// from the random stream (seed, c), and integer counts add up to the same
/// totals in any order. Each thread accumulates into its own CountGrid
/// (writes are deferred into key batches and binned by tile); the grids are
/// merged at the end.
///
/// Run in rounds with RunUntil() so the caller can publish previews between
/// rounds.
class ChaosGame {
 public:
  /// Work unit: plotted steps per chunk (~5-10 ms on one core).
  static constexpr uint64_t kChunkIterations = uint64_t{1} << 20;
  /// Walkers per chunk, each with its own random stream (seed, chunk *
  /// kWalkers + walker), so SIMD lanes and scalar code walk the same paths.
  /// Walker k plots every kWalkers-th step of the chunk, starting at k.
  /// Flames (maps with variations or post transforms, or a final transform
  /// that draws) use flame::kChunkWalkers (64) the same way, so the flame
  /// kernels find whole registers of walkers of one map (docs/chaos_game.md);
  /// a thread steps the walkers of up to flame::kMaxWalkers / 64 chunks
  /// in one block, which changes no walker's path.
  static constexpr int kWalkers = 16;

  /// Validates `params` (non-empty IFS, probabilities, chain shape).
  static absl::StatusOr<std::unique_ptr<ChaosGame>> Create(ChaosGameParams params, int threads);
  ~ChaosGame();

  /// Chunks of a run of `iterations` plotted steps.
  static uint64_t NumChunks(uint64_t iterations) {
    return (iterations + kChunkIterations - 1) / kChunkIterations;
  }
  /// @brief The chunk range [first, second) of shard `index` of `shards`:
  /// floor(N k / S) to floor(N (k + 1) / S) for N chunks, so the shards
  /// tile the run in order and differ in size by at most one chunk.
  static std::pair<uint64_t, uint64_t> ShardChunks(uint64_t iterations, uint32_t shards,
                                                   uint32_t index);

  /// Runs chunks until at least `iterations` steps of this game's range are
  /// done (whole chunks) or the range is complete. Returns CancelledError if
  /// `interrupter` asks to stop.
  absl::Status RunUntil(uint64_t iterations, Interrupter* interrupter);
  /// Runs everything that is left.
  absl::Status Run(Interrupter* interrupter) { return RunUntil(params_.iterations, interrupter); }

  bool done() const { return next_chunk_ == end_chunk_; }
  /// Plotted steps of this game's chunk range (all of them without one).
  uint64_t range_iterations() const;
  const ChaosGameParams& params() const { return params_; }
  ChaosGameStats stats() const;

  /// Per-thread partial counts, for previews between rounds (no merge).
  /// Folds first what the threads still hold in packed words: rounds that
  /// end before the run does leave them there, since a fold scans every
  /// word however few the round added (8 MiB per thread for a 1024²
  /// picture), and a run nobody previews needs only its last.
  const std::vector<CountGrid>& partial_counts();
  /// Merges all threads' counts into one grid and returns it; the game is
  /// spent afterwards.
  CountGrid TakeCounts();

  /// Worst-case memory of a run of `params` on `threads` threads;
  /// `output_bytes_per_voxel` is what the output grids add per active voxel.
  /// `tiles`, when non-zero, is a better bound on the tiles the job
  /// touches (TileCensus::estimate) than the one from the maps' geometry.
  static ChaosGameMemory EstimateMemory(const ChaosGameParams& params, int threads,
                                        uint64_t output_bytes_per_voxel, uint64_t tiles = 0);
  /// @brief Runs `samples` steps of `params` on a grid with one voxel per
  /// tile of the real grid and counts the tiles hit. Cheap (a 2048^3 job's
  /// pilot grid is 64^3); for jobs whose geometric bound is far above what a
  /// thin attractor really touches. With `cell` set, counts cells of that
  /// many voxels instead of tiles (the fast path's census of 8^3 bricks).
  static absl::StatusOr<TileCensus> Pilot(const ChaosGameParams& params, uint64_t samples,
                                          Interrupter* interrupter, Int3 cell = {0, 0, 0});
  /// True when `params` take the fast path: affine maps (drawn
  /// independently or by a chain), no final transform, colour or splatting
  /// (core/affine_walk.h).
  static bool UsesFastPath(const ChaosGameParams& params);
  /// Bytes currently held by the per-thread accumulators and buffers.
  uint64_t MemoryBytes() const;

 private:
  ChaosGame(ChaosGameParams params, int threads);
  struct Worker;
  struct FastChunk;
  struct General;
  // Chunks [first, first + chunks): RunChunkBatch's block, or RunChunk on
  // each in turn.
  void RunChunks(uint64_t first, uint64_t chunks, Worker& worker);
  void RunChunk(uint64_t chunk, Worker& worker);
  // The general path without a chain: the walkers of `chunks` consecutive
  // chunks (at most BatchChunks()) in one block, stepped together by the
  // flame kernel of the SIMD level (core/chaos/flame_walk.h).
  void RunChunkBatch(uint64_t first, uint64_t chunks, Worker& worker);
  // Chunks a thread takes at once: a block's worth for RunChunkBatch
  // (flame::kMaxWalkers / flame_walkers_), fewer near the end of a round
  // so the threads finish together; 1 elsewhere.
  uint64_t BatchChunks() const;
  uint64_t ChunksToTake(uint64_t next, uint64_t target) const;
  // RunChunkBatch's plotting of one round with the plot kernel
  // (core/chaos/flame_plot.h), when there are no arcs and no splatting:
  // walkers [0, active) plot.
  template <typename Rewarm>
  void PlotRound(General& g, const flame::Walkers& s, bool final_map, int n, int active,
                 flame::Plotted& out, Rewarm& rewarm);
  // The fast path (UsesFastPath): the walk kernels of core/affine_walk.h
  // write into per-thread TileBins. Same random streams and arithmetic as
  // RunChunk, so the same counts.
  void RunChunkFast(uint64_t chunk, Worker& worker);
  // Creates the grids and one worker per thread: `entries` per buffer,
  // the fast path's sink (`direct`), one grid for all (`shared`).
  void AddWorkers(size_t entries, bool direct, bool shared);
  // Inside a chunk the interrupter is polled every kPollSteps steps of
  // work, warm-up and re-seeds included, so a cancel lands within about a
  // millisecond whatever the warm-up. RunUntil sets the two pointers.
  struct Poll;
  static constexpr uint64_t kPollSteps = uint64_t{1} << 17;
  bool Stopping(uint64_t chunk);
  Interrupter* poll_intr_ = nullptr;
  std::atomic<bool>* poll_stop_ = nullptr;

  ChaosGameParams params_;
  int threads_;
  uint64_t num_chunks_ = 0;
  uint64_t begin_chunk_ = 0, end_chunk_ = 0;  // the range run (chunk_begin/end)
  uint64_t next_chunk_ = 0;
  bool unfolded_ = false;  // a round left packed words unfolded (partial_counts)
  bool shared_keys_ = false;  // the threads' packed words fold into counts_[0]
  void FoldPending();
  bool FoldSharedByTile();
  std::vector<CountGrid> counts_;  // one per thread, or one shared
  std::unique_ptr<SharedTiles> shared_tiles_;  // when the threads share counts_[0]
  std::mutex fold_lock_;  // packed keys folding into a shared counts_[0] (KeyBins)
  std::vector<std::unique_ptr<Worker>> workers_;
  // Precomputed sampling tables.
  AliasTable map_table_;
  std::vector<AliasTable> state_tables_;
  bool fast_ = false;
  SimdLevel simd_ = SimdLevel::kScalar;
  std::vector<double> affine_coef_;  // 12 per map, for the fast path
  bool planar_ = false;              // walk::AffineWalk::planar for these maps
  // The fast path's maps: the IFS's own, or conjugated into pixel space
  // (view * map * view^-1) for an orthographic image.
  std::vector<Affine3> fast_maps_;
  // The maps and the final map for RunChunkBatch, its kernel and its
  // walkers per chunk (kWalkers for affine maps, flame::kChunkWalkers else).
  FlameProgram program_;
  flame::RoundFn flame_round_ = nullptr;
  // The plot kernel and its target; null where Plot's scalar loop runs
  // (arcs, splatting).
  flame::PlotFn flame_plot_ = nullptr;
  flame::PlotTarget plot_target_;
  int flame_walkers_ = kWalkers;
  // The chain as flat tables for the fast path (walk::ChainTables).
  struct FlatChain {
    std::vector<uint64_t> state, sample, step;
  };
  std::optional<FlatChain> flat_chain_;
};

/// @brief What ChaosGame's Plot computes for points without arcs or
/// splatting, as the plot kernels' data (core/chaos/flame_plot.h): the
/// grid's bounds or the picture's projection, and how a voxel packs into
/// the keys of `grid`, a counter grid of `p`'s CountResolution().
flame::PlotTarget MakePlotTarget(const ChaosGameParams& p, const CountGrid& grid);

}  // namespace nimbus
