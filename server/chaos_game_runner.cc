// Runs chaos-game jobs in rounds of ~0.2 s, publishing progress and
// previews between rounds, and stopping early on convergence.
#include <algorithm>
#include <chrono>

#include "absl/strings/str_cat.h"
#include "core/chaos/chaos_game.h"
#include "server/job_runner.h"

namespace nimbus::server {

namespace {
// Coarse cells per axis for the convergence check.
constexpr int kConvergenceResolution = 32;
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

absl::Status RunChaosGameJob(const spec::ConvertedJob& job, JobContext& ctx) {
  using Clock = std::chrono::steady_clock;
  auto game = ChaosGame::Create(job.chaos_game, ctx.threads());
  if (!game.ok()) return game.status();
  const uint64_t total = job.chaos_game.iterations;
  const ConvergenceParams& conv = job.chaos_game.convergence;
  const bool check_convergence = conv.tolerance > 0;
  uint64_t next_check = conv.check_every;
  std::vector<uint64_t> last_coarse;
  double last_change = -1;
  bool converged = false;
  uint64_t peak_bytes = 0;
  uint64_t step = ChaosGame::kChunkIterations * uint64_t(ctx.threads());
  while (!(*game)->done() && !converged) {
    const uint64_t before = (*game)->stats().iterations_done;
    const auto round_start = Clock::now();
    uint64_t target = before + step;
    // Rounds end on the fixed checkpoints, so where the job stops depends
    // only on the spec, never on timing or the thread count.
    if (check_convergence) target = std::min(target, next_check);
    if (auto st = (*game)->RunUntil(target, ctx.interrupter()); !st.ok()) return st;
    const uint64_t done = (*game)->stats().iterations_done;
    const double round_s =
        std::max(1e-4, std::chrono::duration<double>(Clock::now() - round_start).count());
    step = std::clamp<uint64_t>(uint64_t(double(done - before) * 0.2 / round_s),
                                ChaosGame::kChunkIterations, std::max<uint64_t>(total, 1));
    peak_bytes = std::max(peak_bytes, (*game)->MemoryBytes());
    if (auto st = ctx.ReportProgress(done, total); !st.ok()) return st;
    std::vector<const CountGrid*> parts;
    for (const CountGrid& g : (*game)->partial_counts()) parts.push_back(&g);
    if (check_convergence && done >= next_check && !(*game)->done()) {
      std::vector<uint64_t> coarse = CoarseCounts(parts, kConvergenceResolution);
      if (!last_coarse.empty()) {
        last_change = DensityChange(last_coarse, coarse);
        converged = last_change < conv.tolerance;
      }
      last_coarse = std::move(coarse);
      next_check += conv.check_every;
    }
    ctx.MaybePublishPreview(parts, job.frame, job.density, done);
  }
  const ChaosGameStats stats = (*game)->stats();
  ReportChaosGameStats(stats, ctx);
  const std::string stop_reason = converged ? "converged" : "iterations";
  const CountGrid counts = (*game)->TakeCounts();
  // The output grids come on top of the merged counters.
  uint64_t active_voxels = 0;
  counts.ForEachTile([&](Int3, const uint32_t* t) {
    for (int i = 0; i < CountGrid::kTileVoxels; ++i) active_voxels += t[i] != 0;
  });
  peak_bytes = std::max(peak_bytes, uint64_t(counts.MemoryBytes()) +
                                        active_voxels * OutputBytesPerVoxel(job.density));
  ctx.SetStat("peak_memory_bytes", peak_bytes);
  Metadata meta = ctx.BaseMetadata();
  meta.emplace_back("nimbus_seed", int64_t(job.chaos_game.seed));
  meta.emplace_back("nimbus_iterations", int64_t(stats.iterations_done));
  meta.emplace_back("nimbus_outside", int64_t(stats.outside));
  meta.emplace_back("nimbus_reseeded", int64_t(stats.reseeded));
  meta.emplace_back("nimbus_final_nonfinite", int64_t(stats.final_nonfinite));
  meta.emplace_back("nimbus_stop_reason", stop_reason);
  // Count units per plotted point: raw counts divide by this.
  meta.emplace_back("nimbus_count_scale",
                    int64_t(job.chaos_game.splat ? kSplatScale : 1));
  if (last_change >= 0) meta.emplace_back("nimbus_convergence_change", last_change);
  return WriteDensityVdb(ctx.ResultScratchPath(), counts, job.frame, job.density, meta);
}

}  // namespace nimbus::server
