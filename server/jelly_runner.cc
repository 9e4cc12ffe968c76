// Runs jelly jobs: per frame, pokes and impulses, the physics substeps, the
// frame's leaves, then NAME.0001.vdb… with the density and the velocity
// grid "v", each a preview and a unit of progress. The result is the last
// frame.
#include "core/base/status_macros.h"
#include "core/jelly/jelly_frames.h"
#include "core/jelly/jelly_render.h"
#include "server/job_driver.h"

namespace nimbus::server {

namespace {

struct JellyTotals {
  uint64_t pokes = 0;
  uint64_t clamped = 0;
  uint64_t outside = 0;
  uint64_t leaves = 0;
};

// Physics up to frame `f`: pokes taken from the context first.
absl::Status Advance(const JellyPlan& kind, JellyWorld& world, uint64_t f, JobDriver& d,
                     JellyTotals& totals) {
  if (f == 0) return absl::OkStatus();
  NIMBUS_ASSIGN_OR_RETURN(std::vector<JellyPoke> pokes, d.ctx().TakePokes(f));
  totals.pokes += pokes.size();
  return AdvanceFrame(world, kind, f, pokes, d.interrupter());
}

absl::Status RunFrames(const JellyPlan& kind, JellyWorld& world, JobDriver& d,
                       JellyTotals& totals) {
  const JobPlan& plan = d.plan();
  std::vector<Vec3> leaves, prev;
  JellyFrameGrids grids{CountGrid(plan.frame.resolution), {}, 0};
  nimbus::Metadata meta;
  for (uint64_t f = 0; f < kind.frames; ++f) {
    NIMBUS_RETURN_IF_ERROR(Advance(kind, world, f, d, totals));
    NIMBUS_ASSIGN_OR_RETURN(const uint64_t clamped, FrameLeaves(world, kind, leaves, d.interrupter()));
    totals.clamped += clamped;
    totals.leaves = leaves.size();
    NIMBUS_ASSIGN_OR_RETURN(grids, AccumulateLeaves(leaves, prev, 1.0 / kind.fps, plan.frame,
                                                    kind.velocity_grid, d.interrupter()));
    totals.outside += grids.outside;
    meta = d.Metadata()
               .Add(meta_key::kSeed, int64_t(kind.render.seed))
               .Add(meta_key::kJellyFrame, int64_t(f + 1))
               .Add(meta_key::kJellyTime, world.time())
               .Add(meta_key::kJellyLeaves, int64_t(leaves.size()))
               .Add(meta_key::kJellyPokes, int64_t(totals.pokes))
               .Build();
    std::vector<Vec3Field> fields;
    if (kind.velocity_grid) fields.push_back(grids.velocity);
    NIMBUS_RETURN_IF_ERROR(d.WriteFrame(f, grids.counts, meta, fields));
    d.Preview({&grids.counts}, f + 1);
    NIMBUS_RETURN_IF_ERROR(d.Progress(f + 1, true));
    prev.swap(leaves);
  }
  std::vector<Vec3Field> fields;
  if (kind.velocity_grid) fields.push_back(std::move(grids.velocity));
  return d.WriteResult(grids.counts, meta, fields);
}

}  // namespace

absl::Status RunKind(const JobPlan& plan, const JellyPlan& kind, JobContext& ctx) {
  JobDriver d(plan, ctx);
  absl::StatusOr<JellyWorld> world = JellyWorld::Create(kind.sim);
  if (!world.ok()) return world.status();
  NIMBUS_RETURN_IF_ERROR(d.BeginPhase(JobPhase::kIterating, plan.work.total, plan.work.unit));
  JellyTotals totals;
  if (absl::Status st = RunFrames(kind, *world, d, totals); !st.ok()) {
    // A failed or cancelled run leaves no frames behind (a restarted one
    // writes them again).
    d.DiscardFrames();
    return d.Check(st);
  }
  ctx.SetStat("jelly_frames", kind.frames);
  ctx.SetStat("jelly_steps", world->steps());
  ctx.SetStat("jelly_leaves", totals.leaves);
  ctx.SetStat("jelly_pokes", totals.pokes);
  ctx.SetStat("jelly_clamped_leaves", totals.clamped);
  ctx.SetStat("jelly_outside_leaves", totals.outside);
  return absl::OkStatus();
}

}  // namespace nimbus::server
