// Runs set-IFS jobs (docs/algorithms.md, condensation sets): builds the
// condensation sets and maps from the plan (the preparing phase, warm-up
// included), then either the random iteration into one density volume or
// the book, whose pages are written as numbered frames next to the main
// result as soon as each is finished.
#include <chrono>
#include <optional>

#include "absl/strings/str_cat.h"
#include "core/base/status_macros.h"
#include "core/sets/set_ifs.h"
#include "server/job_driver.h"

namespace nimbus::server {

namespace {

using Clock = std::chrono::steady_clock;

void AddSet(const VoxelSet& set, CountGrid& counts) {
  set.ForEach([&](int x, int y, int z) { counts.Add(x, y, z); });
}

absl::StatusOr<SetMapPtr> BuildMap(const SetMapPlan& m, const GridFrame& frame,
                                   SetBuildCache& cache, Interrupter* intr) {
  if (m.kind == SetMapKind::kPoint) return MakePointSetMap(frame, *m.point);
  NIMBUS_ASSIGN_OR_RETURN(VoxelSet c, BuildSetSource(*m.condensation, frame, &cache, intr));
  absl::StatusOr<SetMapPtr> map;
  switch (m.kind) {
    case SetMapKind::kMedian:
      map = MakeMedianMap(frame, std::move(c), m.median, intr);
      break;
    case SetMapKind::kRotatedMedian:
      map = MakeRotatedMedianMap(frame, std::move(c), m.rotated, intr);
      break;
    case SetMapKind::kConstant:
      map = MakeConstantMap(frame, std::move(c));
      break;
    case SetMapKind::kPoint:
      break;
  }
  if (!map.ok() && !absl::IsCancelled(map.status()))
    return absl::Status(map.status().code(), absl::StrCat(m.field, ": ", map.status().message()));
  return map;
}

// The preparing phase: sketches first (voxelising meshes and precomputing
// closest-point fields is the slow set-up; a sketch used by several maps is
// built once), one progress unit per map and one for the start set.
absl::StatusOr<SetIfs> BuildSetIfs(const SetIfsPlan& plan, JobDriver& d,
                                   std::optional<VoxelSet>& start) {
  const GridFrame& frame = d.plan().frame;
  const uint64_t units = plan.maps.size() + 1 + (plan.book ? 0 : 1);
  NIMBUS_RETURN_IF_ERROR(d.BeginPhase(JobPhase::kPreparing, units, "steps"));
  const auto setup_start = Clock::now();
  SetIfs ifs;
  ifs.frame = frame;
  ifs.probabilities = plan.probabilities;
  ifs.labels = plan.labels;
  SetBuildCache cache;
  for (const SetMapPlan& m : plan.maps) {
    NIMBUS_ASSIGN_OR_RETURN(SetMapPtr map, BuildMap(m, frame, cache, d.interrupter()));
    ifs.maps.push_back(std::move(map));
    NIMBUS_RETURN_IF_ERROR(d.Progress(ifs.maps.size(), true));
  }
  if (plan.start) {
    NIMBUS_ASSIGN_OR_RETURN(start, BuildSetSource(*plan.start, frame, &cache, d.interrupter()));
  }
  NIMBUS_RETURN_IF_ERROR(d.Progress(plan.maps.size() + 1, true));
  d.ctx().SetStat("setup_ms", uint64_t(std::chrono::duration<double, std::milli>(
                                           Clock::now() - setup_start)
                                           .count()));
  return ifs;
}

void ReportRun(const SetIfsPlan& plan, const SetIfsRunStats& stats, JobContext& ctx) {
  ctx.SetStat("set_iterations", stats.iterations);
  ctx.SetStat("voxels_counted", stats.voxels_counted);
  ctx.SetStat("map_ms", uint64_t(stats.map_seconds * 1000));
  ctx.SetStat("nearest_ms", uint64_t(stats.nearest_seconds * 1000));
  for (size_t i = 0; i < stats.map_uses.size(); ++i)
    ctx.SetStat(absl::StrCat("uses_", plan.labels[i]), stats.map_uses[i]);
}

// Random iteration: the warm-up finishes the preparing phase, the counted
// iterations are the iterating phase.
absl::Status RunRandom(const SetIfsPlan& plan, const SetIfs& ifs, std::optional<VoxelSet> start,
                       JobDriver& d) {
  const JobPlan& job = d.plan();
  SetIfsRunOptions o;
  o.iterations = plan.iterations;
  o.warmup = plan.warmup;
  o.seed = plan.seed;
  o.start = std::move(start);
  o.observe_every = 1;
  o.observer = [&](uint64_t counted, const CountGrid& counts, const VoxelSet&) {
    d.Preview({&counts}, counted);
  };
  const uint64_t prepared = plan.maps.size() + 1;
  bool iterating = false;
  d.FollowPolls([&](uint64_t done, uint64_t total) {
    if (total != plan.warmup + plan.iterations) return;  // an inner computation's poll
    if (done < plan.warmup) return void(d.Progress(prepared));
    if (!iterating) iterating = d.BeginPhase(JobPhase::kIterating, job.work.total, job.work.unit).ok();
    (void)d.Progress(done - plan.warmup);
  });
  CountGrid counts(job.frame.resolution);
  auto stats = RunSetIfs(ifs, o, counts, d.interrupter());
  d.FollowPolls(nullptr);
  NIMBUS_RETURN_IF_ERROR(d.Check(stats.status()));
  ReportRun(plan, *stats, d.ctx());
  return d.WriteResult(counts, d.Metadata()
                                   .Add(meta_key::kSeed, int64_t(plan.seed))
                                   .Add(meta_key::kIterations, int64_t(plan.iterations))
                                   .Add(meta_key::kWarmup, int64_t(plan.warmup))
                                   .Build());
}

// The book: page p of N^depth goes to frame p; the main result is the sum
// of all pages (the "X-ray" of the book).
absl::Status RunBookPages(const SetIfsPlan& plan, const SetIfs& ifs, std::optional<VoxelSet> start,
                          JobDriver& d) {
  const JobPlan& job = d.plan();
  NIMBUS_RETURN_IF_ERROR(d.BeginPhase(JobPhase::kIterating, job.work.total, job.work.unit));
  BookOptions o;
  o.depth = plan.depth;
  o.start = std::move(start);
  o.seed = plan.seed;
  o.cache_bytes = plan.book_cache_bytes;
  const Metadata base = d.Metadata().Add(meta_key::kSeed, int64_t(plan.seed)).Build();
  CountGrid sum(job.frame.resolution);
  auto on_page = [&](uint64_t index, const std::string& address,
                     const VoxelSet& page) -> absl::Status {
    CountGrid counts(job.frame.resolution);
    AddSet(page, counts);
    sum.Merge(counts);
    MetadataBuilder meta(base);
    meta.Add(meta_key::kBookAddress, address).Add(meta_key::kBookPage, int64_t(index + 1));
    NIMBUS_RETURN_IF_ERROR(d.WriteFrame(index, counts, meta.Build()));
    d.Preview({&counts}, index + 1);
    return d.Progress(index + 1, true);
  };
  if (absl::Status st = RunBook(ifs, o, on_page, d.interrupter()); !st.ok()) {
    // A failed or cancelled book leaves no pages behind (a restarted one
    // writes them again).
    d.DiscardFrames();
    return d.Check(st);
  }
  d.ctx().SetStat("book_pages", plan.pages);
  MetadataBuilder meta(base);
  meta.Add(meta_key::kBookDepth, int64_t(plan.depth)).Add(meta_key::kBookPages, int64_t(plan.pages));
  return d.WriteResult(sum, meta.Build());
}

}  // namespace

absl::Status RunKind(const JobPlan& plan, const SetIfsPlan& kind, JobContext& ctx) {
  JobDriver d(plan, ctx);
  std::optional<VoxelSet> start;
  absl::StatusOr<SetIfs> ifs = BuildSetIfs(kind, d, start);
  if (!ifs.ok()) return d.Check(ifs.status());
  return kind.book ? RunBookPages(kind, *ifs, std::move(start), d)
                   : RunRandom(kind, *ifs, std::move(start), d);
}

}  // namespace nimbus::server
