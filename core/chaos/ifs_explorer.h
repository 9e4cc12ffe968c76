// @brief The random IFS explorer (docs/explore.md): draws random IFS from
// a seed, keeps the ones whose contraction is below a threshold, frames
// each with a pilot run and draws its thumbnail with the picture pipeline
// (chaos game counted into an image plane, then the look).
#pragma once

#include <cstdint>
#include <functional>
#include <vector>

#include "absl/status/statusor.h"
#include "core/base/interrupter.h"
#include "core/chaos/auto_frame.h"
#include "core/chaos/chaos_game.h"
#include "core/chaos/random_ifs.h"
#include "core/grid/image_look.h"

namespace nimbus {

/// @brief Everything an exploration needs, validated by the spec converter.
struct ExploreParams {
  RandomIfsParams draw;
  uint64_t seed = 0;
  int count = 16;  // candidates to keep
  ContractionMeasure measure = ContractionMeasure::kSingularValue;
  double threshold = 0.9;  // keep when the contraction is below this
  uint64_t max_attempts = 160000;
  int thumbnail_size = 256;
  uint64_t thumbnail_iterations = uint64_t{1} << 21;
  /// Drop a candidate whose thumbnail lights fewer pixels than this.
  double min_coverage = 0.06;
  ColorParams color{ColorMode::kAddress, 0.5};
  /// The thumbnails' look; glow_radius in thumbnail pixels.
  LookParams look;
  /// The pilot that frames each candidate.
  AutoFrameParams frame{0.05, uint64_t{1} << 16, 1e-4};
  uint64_t memory_budget = 0;  // per thumbnail's chaos game; 0: no limit
};

/// @brief A kept candidate: its IFS and how its thumbnail was made, so a
/// spec can render the same picture bigger.
struct ExploreCandidate {
  uint64_t attempt = 0;       // which random IFS of the seed
  double contraction = 0;     // its measure, below the threshold
  ChaosGameParams params;     // IFS, fitted box, seed, warm-up, colour
  double coverage = 0;        // fraction of thumbnail pixels lit
};

/// Warm-up steps of a candidate's walkers (the spec default).
inline constexpr uint32_t kExploreWarmup = 100;

/// The walkers' starting box before framing: around the origin, where a
/// random IFS's attractor lies within a few translation ranges.
Bounds ExploreStartBox(const RandomIfsParams& draw);

/// Called for each kept candidate with its developed thumbnail, in order;
/// an error stops the exploration and is returned.
using ExploreSink = std::function<absl::Status(const ExploreCandidate&, RgbImage thumbnail)>;

/// @brief Summary of a finished exploration.
struct ExploreStats {
  uint64_t attempts = 0;     // random IFS drawn
  uint64_t contractive = 0;  // passed the contraction test
  uint64_t kept = 0;         // passed framing and coverage too
};

/// Draws IFS 0, 1, 2, ... of the seed until `count` are kept or
/// `max_attempts` are drawn. A candidate is kept when its contraction is
/// below the threshold, its pilot frames a finite box, and its thumbnail
/// covers at least min_coverage. Same params, same candidates and bytes,
/// whatever `threads`. CANCELLED when interrupted (polled per candidate and
/// inside each run).
absl::StatusOr<ExploreStats> ExploreIfs(const ExploreParams& params, int threads,
                                        Interrupter* interrupter, const ExploreSink& sink);

}  // namespace nimbus
