// Runs chaos-game jobs in rounds of ~0.2 s, publishing progress and
// previews between rounds.
#include <algorithm>
#include <chrono>

#include "absl/strings/str_cat.h"
#include "core/chaos_game.h"
#include "server/job_runner.h"

namespace nimbus::server {

absl::Status RunChaosGameJob(const spec::ConvertedJob& job, JobContext& ctx) {
  using Clock = std::chrono::steady_clock;
  auto game = ChaosGame::Create(job.chaos_game, ctx.threads());
  if (!game.ok()) return game.status();
  const uint64_t total = job.chaos_game.iterations;
  uint64_t step = ChaosGame::kChunkIterations * uint64_t(ctx.threads());
  while (!(*game)->done()) {
    const uint64_t before = (*game)->stats().iterations_done;
    const auto round_start = Clock::now();
    if (auto st = (*game)->RunUntil(before + step, ctx.interrupter()); !st.ok()) return st;
    const uint64_t done = (*game)->stats().iterations_done;
    const double round_s =
        std::max(1e-4, std::chrono::duration<double>(Clock::now() - round_start).count());
    step = std::clamp<uint64_t>(uint64_t(double(done - before) * 0.2 / round_s),
                                ChaosGame::kChunkIterations, std::max<uint64_t>(total, 1));
    if (auto st = ctx.ReportProgress(done, total); !st.ok()) return st;
    std::vector<const CountGrid*> parts;
    for (const CountGrid& g : (*game)->partial_counts()) parts.push_back(&g);
    ctx.MaybePublishPreview(parts, job.frame, job.density, done);
  }
  const ChaosGameStats stats = (*game)->stats();
  ctx.SetStat("outside", stats.outside);
  ctx.SetStat("reseeded", stats.reseeded);
  if (stats.iterations_done > 0 && stats.reseeded * 1000 > stats.iterations_done)
    ctx.AddWarning(absl::StrCat("high bad-point rate: ", stats.reseeded,
                                " walkers re-seeded after non-finite points in ",
                                stats.iterations_done, " steps"));
  if (stats.iterations_done > 0 && stats.outside * 2 > stats.iterations_done)
    ctx.AddWarning(absl::StrCat(stats.outside, " of ", stats.iterations_done,
                                " points fell outside the grid bounds"));
  const CountGrid counts = (*game)->TakeCounts();
  Metadata meta = ctx.BaseMetadata();
  meta.emplace_back("nimbus_seed", int64_t(job.chaos_game.seed));
  meta.emplace_back("nimbus_iterations", int64_t(stats.iterations_done));
  meta.emplace_back("nimbus_outside", int64_t(stats.outside));
  meta.emplace_back("nimbus_reseeded", int64_t(stats.reseeded));
  return WriteDensityVdb(ctx.ResultScratchPath(), counts, job.frame, job.density, meta);
}

}  // namespace nimbus::server
