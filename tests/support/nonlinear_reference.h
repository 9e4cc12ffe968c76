// A plain, single-threaded chaos game for general (nonlinear) IFS: the
// oracle for ChaosGame's general path. Written as the contract in
// core/chaos/chaos_game.h reads, one walker at a time, with none of the
// engine's buffering, binning, threads or chunk scheduling.
#pragma once

#include <cstdint>
#include <unordered_map>

#include "absl/status/statusor.h"
#include "core/base/random.h"
#include "core/chaos/chaos_game.h"

namespace nimbus::testing {

/// How the reference evaluates a map's nonlinear part.
enum class MapRule {
  /// pre, the weighted sum of EvaluateVariation terms, post: the engine's
  /// variation primitives in a loop of our own. Bitwise the engine's
  /// arithmetic, so counts must agree exactly.
  kEngineVariations,
  /// The same with a few variations re-derived from docs/variations.md
  /// (DocsVariation). Rounding differs, so only statistics agree.
  kDocsVariations,
  /// The pre-affine alone, ignoring variations and post: what a broken
  /// nonlinear path would compute. The final transform is still applied.
  kAffineOnly,
};

/// Visits and colour sum (16-bit fixed point per visit) of one voxel.
struct ReferenceVoxel {
  uint64_t count = 0;
  uint64_t color_sum = 0;
};

/// @brief Sparse result of a reference run, keyed by VoxelIndex.
struct NonlinearReferenceRun {
  Int3 resolution;
  std::unordered_map<uint64_t, ReferenceVoxel> voxels;
  uint64_t outside = 0, reseeded = 0, final_nonfinite = 0;

  uint64_t VoxelIndex(int x, int y, int z) const {
    return (uint64_t(x) * uint64_t(resolution.y) + uint64_t(y)) * uint64_t(resolution.z) +
           uint64_t(z);
  }
  ReferenceVoxel At(int x, int y, int z) const;
  uint64_t Total() const;
};

/// @brief Runs `params` the simple way: chunk c of kChunkIterations plotted
/// steps has W walkers (16 when the maps are affine and the final transform
/// draws nothing, else 64); walker k draws from Rng(seed, W c + k), starts at
/// a uniform point of the bounds (then its colour, when coloured), takes
/// `warmup` unplotted steps (re-seeding non-finite points), and plots steps
/// k, k + W, ... of the chunk. Every step draws the same number of words:
/// one that picks the map, then as many as the hungriest map's random
/// variations read (each term its own in turn), then the final transform's.
/// A non-finite step re-seeds and warms the walker up again and plots
/// nothing. Plotted points go through the final transform, then fall in a
/// voxel or outside. Not supported: chains, arcs, splatting
/// (InvalidArgument).
absl::StatusOr<NonlinearReferenceRun> RunNonlinearReference(const ChaosGameParams& params,
                                                            MapRule rule);

/// True for the variations DocsVariation implements: linear, sinusoidal,
/// spherical, swirl, julia, bubble, blur, noise and polar_doubling.
bool HasDocsVariation(VariationKind kind);

/// Pre-drawn random words read in turn: a uniform is word >> 11 times
/// 2^-53, like Rng::Uniform.
struct WordCursor {
  const uint64_t* next;
  uint64_t Next() { return *next++; }
  double Uniform() { return double(Next() >> 11) * 0x1.0p-53; }
};

/// Unweighted variation `kind` at `q`, from the formula in
/// docs/variations.md (atan2 and complex arithmetic where the engine uses
/// ratios), reading from `words` as many as documented.
Vec3 DocsVariation(VariationKind kind, Vec3 q, WordCursor& words);

}  // namespace nimbus::testing
