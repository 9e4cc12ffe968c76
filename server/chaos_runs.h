// Pieces the point-IFS runners share (chaos_game_runner.cc,
// matrix_runner.cc): a chaos game driven in rounds and its reports.
#pragma once

#include <cstdint>
#include <vector>

#include "core/chaos/chaos_game.h"
#include "server/job_driver.h"

namespace nimbus::server {

/// Publishes a chaos game's counters as job stats and warns when many
/// points went non-finite or fell outside the grid.
void ReportChaosGameStats(const ChaosGameStats& stats, JobContext& ctx);

/// Rounds that advance `game`; previews show `fixed_parts` plus the game's
/// partial counts; `peak_bytes` (may be null) tracks the game's memory.
JobDriver::Rounds ChaosRounds(ChaosGame& game, JobDriver& driver, uint64_t offset,
                              std::vector<const CountGrid*> fixed_parts, uint64_t* peak_bytes);

/// How a chaos game's run ended, for the result's metadata.
struct ChaosStop {
  bool converged = false;
  double last_change = -1;  // < 0: no convergence check ran
  uint64_t peak_bytes = 0;  // of the run, before the output grids
};

/// The finishing every chaos-game job shares, sharded (the merge) or not:
/// counters and warnings, metadata, and the written density of `counts`.
absl::Status FinishChaosGame(const JobPlan& plan, JobDriver& d, const ChaosGameParams& params,
                             const CountGrid& counts, const ChaosGameStats& stats,
                             const ChaosStop& stop);

/// Runs one chaos game as the whole job and writes its density.
absl::Status RunChaosGameParams(const JobPlan& plan, ChaosGameParams params, JobContext& ctx);
/// The same inside the iterating phase of `driver`, whose progress starts
/// at `offset` units.
absl::Status RunChaosVolume(JobDriver& driver, ChaosGameParams params, uint64_t offset,
                            JobContext& ctx);
/// A chaos game with grid.auto_frame or an image (chaos_image_runner.cc):
/// fits the box, counts the picture, then the volume unless image_only.
absl::Status RunChaosPicture(const JobPlan& plan, const ChaosGamePlan& kind, JobContext& ctx);

}  // namespace nimbus::server
