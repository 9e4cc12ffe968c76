// IFS whose maps act on whole voxel sets (docs/algorithms.md#ifs-with-condensation-on-voxel-sets): the
// random iteration that accumulates the measure attractor into a CountGrid,
// and the deterministic "book of drawings".
#pragma once

#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/grid/count_grid.h"
#include "core/base/geometry.h"
#include "core/base/interrupter.h"
#include "core/sets/set_maps.h"
#include "core/grid/voxel_set.h"

namespace nimbus {

/// @brief A set IFS: maps on voxel sets over one frame, with probabilities.
struct SetIfs {
  GridFrame frame;
  std::vector<SetMapPtr> maps;
  /// One per map, non-negative with a positive sum (normalised here);
  /// empty means equal probabilities.
  std::vector<double> probabilities;
  /// Address letters of the maps for book pages; empty means "A", "B", ...
  std::vector<std::string> labels;
};

/// Checks maps (non-null, same frame), probabilities and labels.
absl::Status ValidateSetIfs(const SetIfs& ifs);

/// A seeded solid ball of a quarter of the smallest grid extent: the default
/// start set (the attractor forgets it within a few iterations).
VoxelSet DefaultStartSet(const GridFrame& frame, uint64_t seed);

struct SetIfsRunOptions {
  /// Iterations whose sets are counted (after the warm-up).
  uint64_t iterations = 300;
  /// Iterations run before counting starts. Median maps roughly halve the
  /// distance to their condensation set per step, so a few tens forget any
  /// start set to within a voxel.
  uint64_t warmup = 16;
  uint64_t seed = 1;
  /// Start set; DefaultStartSet(frame, seed) when unset.
  std::optional<VoxelSet> start;
  /// Call `observer` after every this many counted iterations (0 = never).
  uint64_t observe_every = 0;
  /// Preview hook: counted iterations so far, the counts, the current set.
  std::function<void(uint64_t counted, const CountGrid& counts, const VoxelSet& current)> observer;
};

struct SetIfsRunStats {
  uint64_t iterations = 0;         // including warm-up
  std::vector<uint64_t> map_uses;  // per map
  uint64_t voxels_counted = 0;     // sum of counted set sizes
  double seconds = 0;              // whole run
  double map_seconds = 0;          // inside SetMap::Apply
  double nearest_seconds = 0;      // per-step feature transforms
  double count_seconds = 0;        // adding sets to the CountGrid
};

/// @brief Random iteration on sets: pick f_i with probability p_i, set
/// I_{k+1} = f_i(I_k), and after the warm-up add 1 to `counts` for every
/// voxel of I_{k+1}. The counts approximate the measure attractor ("X-ray of
/// the book"). Deterministic for a seed. Polls `interrupter` with
/// (iterations done, total) and returns CancelledError when asked to stop;
/// `counts` then holds the iterations finished so far.
absl::StatusOr<SetIfsRunStats> RunSetIfs(const SetIfs& ifs, const SetIfsRunOptions& options,
                                         CountGrid& counts, Interrupter* interrupter = nullptr);

struct BookOptions {
  /// Number of map applications per page; N maps give N^depth pages.
  int depth = 4;
  /// Start set; DefaultStartSet(frame, seed) when unset.
  std::optional<VoxelSet> start;
  /// Seed of the maps' random numbers (only nonlinear point maps use them).
  uint64_t seed = 1;
  /// Memory for intermediate sets shared by many pages. More memory, fewer
  /// map applications: with room for N^(depth-1) sets each page costs one.
  uint64_t cache_bytes = uint64_t{512} << 20;
};

/// Receives page `index` (0-based, in address order), its address (labels
/// of the maps, outermost first: "AB" is f_A(f_B(start))) and its set.
/// A non-OK status stops the book and is returned.
using BookPageCallback =
    std::function<absl::Status(uint64_t index, const std::string& address, const VoxelSet& page)>;

/// Pages of a book: maps^depth, or an error beyond 2^20 pages.
absl::StatusOr<uint64_t> BookPageCount(size_t maps, int depth);

/// @brief The deterministic algorithm on sets: every composition of `depth`
/// maps applied to the start set, delivered page by page in address order
/// (with two median maps, a morph from A to B) as soon as each is done.
absl::Status RunBook(const SetIfs& ifs, const BookOptions& options, const BookPageCallback& on_page,
                     Interrupter* interrupter = nullptr);

}  // namespace nimbus
