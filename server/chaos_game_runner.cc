// Runs chaos-game jobs in rounds of ~0.2 s through the job driver,
// publishing progress and previews between rounds, and stopping early on
// convergence at fixed checkpoints.
#include <algorithm>

#include "absl/strings/str_cat.h"
#include "core/base/status_macros.h"
#include "core/chaos/chaos_game.h"
#include "server/chaos_runs.h"
#include "server/job_driver.h"

namespace nimbus::server {

namespace {
// Coarse cells per axis for the convergence check.
constexpr int kConvergenceResolution = 32;

// Compares coarse densities at the checkpoints; remembers the last change.
struct ConvergenceCheck {
  double tolerance = 0;
  std::vector<uint64_t> last_coarse;
  double last_change = -1;
  bool converged = false;

  bool AtCheckpoint(const std::vector<const CountGrid*>& parts) {
    std::vector<uint64_t> coarse = CoarseCounts(parts, kConvergenceResolution);
    if (!last_coarse.empty()) {
      last_change = DensityChange(last_coarse, coarse);
      converged = last_change < tolerance;
    }
    last_coarse = std::move(coarse);
    return converged;
  }
};

}  // namespace

void ReportChaosGameStats(const ChaosGameStats& stats, JobContext& ctx) {
  ctx.SetStat("outside", stats.outside);
  ctx.SetStat("reseeded", stats.reseeded);
  ctx.SetStat("final_nonfinite", stats.final_nonfinite);
  if (stats.iterations_done > 0 && stats.reseeded * 1000 > stats.iterations_done)
    ctx.AddWarning(absl::StrCat("high bad-point rate: ", stats.reseeded,
                                " walkers re-seeded after non-finite points in ",
                                stats.iterations_done, " steps"));
  if (stats.iterations_done > 0 && stats.final_nonfinite * 1000 > stats.iterations_done)
    ctx.AddWarning(absl::StrCat("the final transform made ", stats.final_nonfinite, " of ",
                                stats.iterations_done, " plotted points non-finite"));
  if (stats.iterations_done > 0 && stats.outside * 2 > stats.iterations_done)
    ctx.AddWarning(absl::StrCat(stats.outside, " of ", stats.iterations_done,
                                " points fell outside the grid bounds"));
}

JobDriver::Rounds ChaosRounds(ChaosGame& game, JobDriver& driver, uint64_t offset,
                              std::vector<const CountGrid*> fixed_parts, uint64_t* peak_bytes) {
  JobDriver::Rounds r;
  r.offset = offset;
  r.total = game.range_iterations();
  r.min_step = ChaosGame::kChunkIterations;
  r.first_step = ChaosGame::kChunkIterations * uint64_t(driver.ctx().threads());
  r.step_multiple = r.first_step;
  r.advance = [&game, &driver, peak_bytes](uint64_t target) -> absl::StatusOr<uint64_t> {
    NIMBUS_RETURN_IF_ERROR(game.RunUntil(target, driver.interrupter()));
    if (peak_bytes) *peak_bytes = std::max(*peak_bytes, game.MemoryBytes());
    return game.stats().iterations_done;
  };
  r.finished = [&game] { return game.done(); };
  r.parts = [&game, fixed_parts] {
    std::vector<const CountGrid*> parts = fixed_parts;
    for (const CountGrid& g : game.partial_counts()) parts.push_back(&g);
    return parts;
  };
  return r;
}

absl::Status RunChaosGameParams(const JobPlan& plan, ChaosGameParams params, JobContext& ctx) {
  JobDriver d(plan, ctx);
  NIMBUS_RETURN_IF_ERROR(d.BeginPhase(JobPhase::kIterating, plan.work.total, plan.work.unit));
  return RunChaosVolume(d, std::move(params), 0, ctx);
}

absl::Status RunChaosVolume(JobDriver& d, ChaosGameParams params, uint64_t offset,
                            JobContext& ctx) {
  const JobPlan& plan = d.plan();
  params.memory_budget = ctx.memory_budget();
  NIMBUS_ASSIGN_OR_RETURN(auto game, ChaosGame::Create(std::move(params), ctx.threads()));
  uint64_t peak_bytes = 0;
  JobDriver::Rounds rounds = ChaosRounds(*game, d, offset, {}, &peak_bytes);
  ConvergenceCheck conv;
  conv.tolerance = game->params().convergence.tolerance;
  if (conv.tolerance > 0) {
    rounds.checkpoint_every = game->params().convergence.check_every;
    rounds.at_checkpoint = [&](uint64_t) { return conv.AtCheckpoint(rounds.parts()); };
  }
  NIMBUS_RETURN_IF_ERROR(d.RunRounds(rounds));
  const ChaosGameStats stats = game->stats();
  const CountGrid counts = game->TakeCounts();
  return FinishChaosGame(plan, d, game->params(), counts, stats,
                         {conv.converged, conv.last_change, peak_bytes});
}

absl::Status FinishChaosGame(const JobPlan& plan, JobDriver& d, const ChaosGameParams& params,
                             const CountGrid& counts, const ChaosGameStats& stats,
                             const ChaosStop& stop) {
  JobContext& ctx = d.ctx();
  ReportChaosGameStats(stats, ctx);
  // The output grids come on top of the merged counters.
  uint64_t active_voxels = 0;
  counts.ForEachTile([&](Int3, const uint32_t* t) {
    for (int i = 0; i < CountGrid::kTileVoxels; ++i) active_voxels += t[i] != 0;
  });
  const uint64_t peak_bytes =
      std::max(stop.peak_bytes, uint64_t(counts.MemoryBytes()) +
                                    active_voxels * OutputBytesPerVoxel(plan.density));
  ctx.SetStat("peak_memory_bytes", peak_bytes);
  MetadataBuilder meta = d.Metadata();
  meta.Add(meta_key::kSeed, int64_t(params.seed))
      .ChaosStats(stats)
      .Add(meta_key::kFinalNonfinite, int64_t(stats.final_nonfinite))
      .Add(meta_key::kStopReason, stop.converged ? "converged" : "iterations")
      // Count units per plotted point: raw counts divide by this.
      .Add(meta_key::kCountScale, int64_t(params.splat ? kSplatScale : 1));
  if (stop.last_change >= 0) meta.Add(meta_key::kConvergenceChange, stop.last_change);
  return d.WriteResult(counts, meta.Build());
}

absl::Status RunKind(const JobPlan& plan, const ChaosGamePlan& kind, JobContext& ctx) {
  if (!kind.image && !kind.auto_frame) return RunChaosGameParams(plan, kind.params, ctx);
  return RunChaosPicture(plan, kind, ctx);
}

}  // namespace nimbus::server
