// The 3D chaos game (random iteration) for point IFS and graph-directed
// (recurrent) IFS, accumulating integer visit counts.
#pragma once

#include <cstdint>
#include <optional>
#include <vector>

#include "absl/status/statusor.h"
#include "core/count_grid.h"
#include "core/geometry.h"
#include "core/interrupter.h"
#include "core/point_map.h"

namespace nimbus {

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
};

/// Counters a run reports; all exact and independent of the thread count.
struct ChaosGameStats {
  uint64_t iterations_done = 0;  // plotted-or-outside steps finished
  uint64_t outside = 0;          // steps whose point fell outside the grid bounds
  uint64_t reseeded = 0;         // walkers restarted after a non-finite point
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
  /// Independent walkers interleaved per chunk, to overlap memory latency.
  static constexpr int kWalkers = 8;

  /// Validates `params` (non-empty IFS, probabilities, chain shape).
  static absl::StatusOr<std::unique_ptr<ChaosGame>> Create(ChaosGameParams params, int threads);
  ~ChaosGame();

  /// Runs chunks until at least `iterations` steps are done (whole chunks) or
  /// the job is complete. Returns CancelledError if `interrupter` asks to stop.
  absl::Status RunUntil(uint64_t iterations, Interrupter* interrupter);
  /// Runs everything that is left.
  absl::Status Run(Interrupter* interrupter) { return RunUntil(params_.iterations, interrupter); }

  bool done() const { return next_chunk_ == num_chunks_; }
  const ChaosGameParams& params() const { return params_; }
  ChaosGameStats stats() const;

  /// Per-thread partial counts, for previews between rounds (no merge).
  const std::vector<CountGrid>& partial_counts() const { return counts_; }
  /// Merges all threads' counts into one grid and returns it; the game is
  /// spent afterwards.
  CountGrid TakeCounts();

  /// Bytes this game may need at most: one full CountGrid per thread.
  static uint64_t EstimateMemoryBytes(Int3 resolution, int threads);

 private:
  ChaosGame(ChaosGameParams params, int threads);
  struct Worker;
  void RunChunk(uint64_t chunk, Worker& worker);

  ChaosGameParams params_;
  int threads_;
  uint64_t num_chunks_ = 0;
  uint64_t next_chunk_ = 0;
  std::vector<CountGrid> counts_;
  std::vector<std::unique_ptr<Worker>> workers_;
  // Precomputed sampling tables.
  AliasTable map_table_;
  std::vector<AliasTable> state_tables_;
};

}  // namespace nimbus
