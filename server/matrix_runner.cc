// Runs IFS-matrix jobs (chaos_game.matrices). Without a component grid the
// plan's whole run is an ordinary chaos game and runs as one. With a
// component grid each selected component runs on its own chain, because the
// engine counts plotted points without their labels; the runs are summed
// into the density and their argmax per voxel becomes the `component` grid.
#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "core/base/status_macros.h"
#include "core/matrix/component_grid.h"
#include "server/chaos_runs.h"
#include "server/job_driver.h"

namespace nimbus::server {

namespace {

void ReportMatrix(const IfsMatrixPlan& plan, JobContext& ctx) {
  ctx.SetStat("matrix_size", plan.matrix.size());
  ctx.SetStat("matrix_map_references", plan.matrix.MapReferences());
  ctx.SetStat("matrix_table_maps", plan.maps.size());
  ctx.SetStat("matrix_chain_states", plan.chain_states);
  ctx.SetStat("matrix_components", plan.selection.size());
}

void Accumulate(ChaosGameStats& sum, const ChaosGameStats& s) {
  sum.iterations_done += s.iterations_done;
  sum.outside += s.outside;
  sum.reseeded += s.reseeded;
  sum.final_nonfinite += s.final_nonfinite;
}

// Runs the component runs one after another into `acc`.
absl::StatusOr<ChaosGameStats> RunComponents(const IfsMatrixPlan& plan, JobDriver& d,
                                             ComponentAccumulator& acc) {
  ChaosGameStats sum;
  for (size_t c = 0; c < plan.component_runs.size(); ++c) {
    ChaosGameParams params = plan.component_runs[c];
    params.memory_budget = d.ctx().memory_budget();
    NIMBUS_ASSIGN_OR_RETURN(auto game, ChaosGame::Create(std::move(params), d.ctx().threads()));
    // Previews show the finished components plus the running one.
    NIMBUS_RETURN_IF_ERROR(
        d.RunRounds(ChaosRounds(*game, d, sum.iterations_done, {&acc.density()}, nullptr)));
    Accumulate(sum, game->stats());
    acc.Add(int32_t(c), game->TakeCounts());
  }
  return sum;
}

}  // namespace

absl::Status RunKind(const JobPlan& plan, const IfsMatrixPlan& kind, JobContext& ctx) {
  ReportMatrix(kind, ctx);
  if (kind.component_grid == ComponentGridType::kNone)
    return RunChaosGameParams(plan, kind.run, ctx);
  JobDriver d(plan, ctx);
  NIMBUS_RETURN_IF_ERROR(d.BeginPhase(JobPhase::kIterating, plan.work.total, plan.work.unit));
  ComponentAccumulator acc(plan.frame.resolution);
  NIMBUS_ASSIGN_OR_RETURN(const ChaosGameStats sum, RunComponents(kind, d, acc));
  ReportChaosGameStats(sum, ctx);
  const std::vector<uint64_t> voxels = acc.VoxelsPerLabel();
  std::vector<std::string> labels;
  for (size_t c = 0; c < kind.selection.size(); ++c) {
    ctx.SetStat(absl::StrCat("component_", c, "_voxels"), c < voxels.size() ? voxels[c] : 0);
    labels.push_back(
        absl::StrCat(c, "=(", kind.selection[c].row, ",", kind.selection[c].col, ")"));
  }
  MetadataBuilder meta = d.Metadata();
  meta.Add(meta_key::kSeed, int64_t(kind.run.seed))
      .ChaosStats(sum)
      .Add(meta_key::kComponents, absl::StrJoin(labels, " "));
  NIMBUS_RETURN_IF_ERROR(d.BeginPhase(JobPhase::kWriting, 1, "files"));
  // Int32 ids go to a file of their own beside the result: pyopenvdb and
  // Blender cannot open a file holding an Int32 grid, and the result always
  // carries the ids as floats.
  std::filesystem::path int32_path;
  if (kind.component_grid == ComponentGridType::kInt) {
    NIMBUS_ASSIGN_OR_RETURN(int32_path, d.ExtraFilePath(plan.name + ".component.vdb"));
  }
  NIMBUS_RETURN_IF_ERROR(WriteDensityAndComponentVdb(ctx.ResultScratchPath(), acc, plan.frame,
                                                     plan.density, kind.component_grid,
                                                     meta.Build(), int32_path));
  return d.Progress(1, true);
}

}  // namespace nimbus::server
