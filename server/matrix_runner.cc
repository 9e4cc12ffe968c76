// Runs IFS-matrix jobs (chaos_game.matrices). Without a component grid the
// converted job is an ordinary chaos game (a chain over the expanded map
// table, or a plain IFS for 1x1 matrices) and runs as one. With a component
// grid each selected component runs on its own chain, because the engine
// counts plotted points without their labels; the runs are summed into the
// density and their argmax per voxel becomes the `component` grid.
#include <algorithm>
#include <chrono>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "core/chaos/chaos_game.h"
#include "core/matrix/component_grid.h"
#include "proto/convert_matrix.h"
#include "server/job_runner.h"

namespace nimbus::server {

absl::Status RunIfsMatrixJob(const spec::ConvertedJob& job, JobContext& ctx) {
  const spec::IfsMatrixPlan* plan = job.ifs_matrix.get();
  if (plan == nullptr) return absl::InternalError("IFS-matrix job without a plan");
  ctx.SetStat("matrix_size", plan->matrix.size());
  ctx.SetStat("matrix_map_references", plan->matrix.MapReferences());
  ctx.SetStat("matrix_table_maps", plan->maps.size());
  ctx.SetStat("matrix_chain_states", plan->chain_states);
  ctx.SetStat("matrix_components", plan->selection.size());
  if (plan->component_grid == ComponentGridType::kNone) return RunChaosGameJob(job, ctx);

  using Clock = std::chrono::steady_clock;
  const uint64_t total = job.chaos_game.iterations;
  ComponentAccumulator acc(job.frame.resolution);
  ChaosGameStats sum;
  uint64_t finished = 0;  // iterations of completed component runs
  for (size_t c = 0; c < plan->component_runs.size(); ++c) {
    auto game = ChaosGame::Create(plan->component_runs[c], ctx.threads());
    if (!game.ok()) return game.status();
    uint64_t step = ChaosGame::kChunkIterations * uint64_t(ctx.threads());
    const uint64_t run_total = plan->component_runs[c].iterations;
    while (!(*game)->done()) {
      const uint64_t before = (*game)->stats().iterations_done;
      const auto round_start = Clock::now();
      if (auto st = (*game)->RunUntil(before + step, ctx.interrupter()); !st.ok()) return st;
      const uint64_t done = (*game)->stats().iterations_done;
      const double round_s =
          std::max(1e-4, std::chrono::duration<double>(Clock::now() - round_start).count());
      step = std::clamp<uint64_t>(uint64_t(double(done - before) * 0.2 / round_s),
                                  ChaosGame::kChunkIterations, std::max<uint64_t>(run_total, 1));
      if (auto st = ctx.ReportProgress(finished + done, total); !st.ok()) return st;
      // Previews show the finished components plus the running one.
      std::vector<const CountGrid*> parts{&acc.density()};
      for (const CountGrid& g : (*game)->partial_counts()) parts.push_back(&g);
      ctx.MaybePublishPreview(parts, job.frame, job.density, finished + done);
    }
    const ChaosGameStats stats = (*game)->stats();
    sum.iterations_done += stats.iterations_done;
    sum.outside += stats.outside;
    sum.reseeded += stats.reseeded;
    sum.final_nonfinite += stats.final_nonfinite;
    finished += stats.iterations_done;
    const CountGrid counts = (*game)->TakeCounts();
    acc.Add(int32_t(c), counts);
  }
  ReportChaosGameStats(sum, ctx);
  const std::vector<uint64_t> voxels = acc.VoxelsPerLabel();
  for (size_t c = 0; c < plan->selection.size(); ++c)
    ctx.SetStat(absl::StrCat("component_", c, "_voxels"), c < voxels.size() ? voxels[c] : 0);

  std::vector<std::string> labels;
  for (size_t c = 0; c < plan->selection.size(); ++c)
    labels.push_back(
        absl::StrCat(c, "=(", plan->selection[c].row, ",", plan->selection[c].col, ")"));
  Metadata meta = ctx.BaseMetadata();
  meta.emplace_back("nimbus_seed", int64_t(job.chaos_game.seed));
  meta.emplace_back("nimbus_iterations", int64_t(sum.iterations_done));
  meta.emplace_back("nimbus_outside", int64_t(sum.outside));
  meta.emplace_back("nimbus_reseeded", int64_t(sum.reseeded));
  meta.emplace_back("nimbus_components", absl::StrJoin(labels, " "));
  return WriteDensityAndComponentVdb(ctx.ResultScratchPath(), acc, job.frame, job.density,
                                     plan->component_grid, meta);
}

}  // namespace nimbus::server
