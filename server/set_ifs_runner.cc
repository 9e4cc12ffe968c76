// Runs set-IFS jobs (ALGORITHMS.md section 1): builds the condensation sets
// and maps from the plan, then either the random iteration into one density
// volume or the book, whose pages are written as a numbered morph sequence
// next to the main result as soon as each is finished.
#include <chrono>
#include <cstdio>
#include <thread>

#include "absl/strings/str_cat.h"
#include "core/sets/set_ifs.h"
#include "proto/convert_set_ifs.h"
#include "server/job_runner.h"
#include "server/result_store.h"

namespace nimbus::server {

namespace {

using Clock = std::chrono::steady_clock;

// Forwards cancellation to the job and, when the engine's top-level loop
// polls from the worker thread, publishes progress (at most every 0.2 s).
// Inner computations poll with their own totals and from TBB threads; they
// only get the cancellation answer.
class JobProgress final : public Interrupter {
 public:
  JobProgress(JobContext& ctx, uint64_t total) : ctx_(ctx), total_(total) {}

  bool WasInterrupted(uint64_t done, uint64_t total) override {
    if (aborted_.load(std::memory_order_relaxed)) return true;
    if (ctx_.interrupter()->WasInterrupted(done, total)) return true;
    if (reporting_total_ != 0 && total == reporting_total_ && std::this_thread::get_id() == owner_)
      Report(offset_ + done);
    return false;
  }

  // Reports `done` of the job's total if 0.2 s have passed (or `force`).
  void Report(uint64_t done, bool force = false) {
    if (std::this_thread::get_id() != owner_) return;
    const auto now = Clock::now();
    if (!force && now - last_ < std::chrono::milliseconds(200)) return;
    last_ = now;
    if (!ctx_.ReportProgress(std::min(done, total_), total_).ok()) aborted_ = true;
  }
  // Engine polls whose total is `total` become progress `offset + done`.
  void Follow(uint64_t total, uint64_t offset) {
    reporting_total_ = total;
    offset_ = offset;
  }
  bool aborted() const { return aborted_; }

 private:
  JobContext& ctx_;
  const uint64_t total_;
  const std::thread::id owner_ = std::this_thread::get_id();
  uint64_t reporting_total_ = 0;
  uint64_t offset_ = 0;
  Clock::time_point last_;
  std::atomic<bool> aborted_{false};
};

absl::Status Finish(const absl::Status& s, const JobProgress& progress) {
  if (progress.aborted()) return absl::AbortedError("lost the job's claim");
  return s;
}

void AddSet(const VoxelSet& set, CountGrid& counts) {
  set.ForEach([&](int x, int y, int z) { counts.Add(x, y, z); });
}

absl::StatusOr<SetMapPtr> BuildMap(const spec::SetMapPlan& m, const GridFrame& frame,
                                   spec::SetBuildCache& cache, Interrupter* intr) {
  if (m.kind == SetMapKind::kPoint) return MakePointSetMap(frame, *m.point);
  auto c = spec::BuildSetSource(*m.condensation, frame, &cache, intr);
  if (!c.ok()) return c.status();
  absl::StatusOr<SetMapPtr> map;
  switch (m.kind) {
    case SetMapKind::kMedian:
      map = MakeMedianMap(frame, std::move(*c), m.median, intr);
      break;
    case SetMapKind::kRotatedMedian:
      map = MakeRotatedMedianMap(frame, std::move(*c), m.rotated, intr);
      break;
    case SetMapKind::kConstant:
      map = MakeConstantMap(frame, std::move(*c));
      break;
    case SetMapKind::kPoint:
      break;
  }
  if (!map.ok() && !absl::IsCancelled(map.status()))
    return absl::Status(map.status().code(), absl::StrCat(m.field, ": ", map.status().message()));
  return map;
}

std::string PageFileName(const std::string& name, uint64_t index) {
  char buf[32];
  std::snprintf(buf, sizeof buf, ".%04llu.vdb", static_cast<unsigned long long>(index + 1));
  return name + buf;
}

}  // namespace

absl::Status RunSetIfsJob(const spec::ConvertedJob& job, JobContext& ctx) {
  const spec::SetIfsPlan& plan = *job.set_ifs;
  JobProgress progress(ctx, job.total_work);
  progress.Report(0, true);

  // Sketches first: voxelising meshes and precomputing closest-point fields
  // is the slow set-up; a sketch used by several maps is voxelised once.
  SetIfs ifs;
  ifs.frame = job.frame;
  ifs.probabilities = plan.probabilities;
  ifs.labels = plan.labels;
  spec::SetBuildCache cache;
  const auto setup_start = Clock::now();
  for (const spec::SetMapPlan& m : plan.maps) {
    auto map = BuildMap(m, job.frame, cache, &progress);
    if (!map.ok()) return Finish(map.status(), progress);
    ifs.maps.push_back(std::move(*map));
    progress.Report(0, true);
  }
  std::optional<VoxelSet> start;
  if (plan.start) {
    auto s = spec::BuildSetSource(*plan.start, job.frame, &cache, &progress);
    if (!s.ok()) return Finish(s.status(), progress);
    start = std::move(*s);
  }
  cache.sets.clear();
  ctx.SetStat(
      "setup_ms",
      uint64_t(std::chrono::duration<double, std::milli>(Clock::now() - setup_start).count()));

  Metadata meta = ctx.BaseMetadata();
  meta.emplace_back("nimbus_seed", int64_t(plan.seed));
  const std::filesystem::path main_path = ctx.ResultScratchPath();

  if (!plan.book) {
    SetIfsRunOptions o;
    o.iterations = plan.iterations;
    o.warmup = plan.warmup;
    o.seed = plan.seed;
    o.start = std::move(start);
    o.observe_every = 1;
    o.observer = [&](uint64_t counted, const CountGrid& counts, const VoxelSet&) {
      ctx.MaybePublishPreview({&counts}, job.frame, job.density, plan.warmup + counted);
    };
    CountGrid counts(job.frame.resolution);
    progress.Follow(plan.warmup + plan.iterations, 0);
    auto stats = RunSetIfs(ifs, o, counts, &progress);
    if (!stats.ok()) return Finish(stats.status(), progress);
    progress.Report(job.total_work, true);
    ctx.SetStat("set_iterations", stats->iterations);
    ctx.SetStat("voxels_counted", stats->voxels_counted);
    ctx.SetStat("map_ms", uint64_t(stats->map_seconds * 1000));
    ctx.SetStat("nearest_ms", uint64_t(stats->nearest_seconds * 1000));
    for (size_t i = 0; i < stats->map_uses.size(); ++i)
      ctx.SetStat(absl::StrCat("uses_", plan.labels[i]), stats->map_uses[i]);
    meta.emplace_back("nimbus_iterations", int64_t(plan.iterations));
    meta.emplace_back("nimbus_warmup", int64_t(plan.warmup));
    return Finish(WriteDensityVdb(main_path, counts, job.frame, job.density, meta), progress);
  }

  // The book: page p of N^depth goes to NAME.<p+1>.vdb; the main result is
  // the sum of all pages (the "X-ray" of the book).
  const std::filesystem::path pages_dir = ExtraFilesDir(main_path);
  std::error_code ec;
  std::filesystem::remove_all(pages_dir, ec);  // a previous attempt's pages
  std::filesystem::create_directories(pages_dir, ec);
  if (ec) return absl::InternalError(absl::StrCat("cannot create ", pages_dir.string()));
  BookOptions o;
  o.depth = plan.depth;
  o.start = std::move(start);
  o.seed = plan.seed;
  o.cache_bytes = plan.book_cache_bytes;
  CountGrid sum(job.frame.resolution);
  auto on_page = [&](uint64_t index, const std::string& address,
                     const VoxelSet& page) -> absl::Status {
    CountGrid counts(job.frame.resolution);
    AddSet(page, counts);
    sum.Merge(counts);
    Metadata page_meta = meta;
    page_meta.emplace_back("nimbus_book_address", address);
    page_meta.emplace_back("nimbus_book_page", int64_t(index + 1));
    // WriteDensityVdb renames a finished file into place, so a listed page
    // is always complete and can be fetched while later pages are running.
    if (auto st = WriteDensityVdb(pages_dir / PageFileName(job.name, index), counts, job.frame,
                                  job.density, page_meta);
        !st.ok())
      return st;
    progress.Report(index + 1, true);
    ctx.MaybePublishPreview({&counts}, job.frame, job.density, index + 1);
    return progress.aborted() ? absl::AbortedError("lost the job's claim") : absl::OkStatus();
  };
  if (auto st = RunBook(ifs, o, on_page, &progress); !st.ok()) {
    // A failed or cancelled book leaves no pages behind (a restarted one
    // writes them again).
    std::filesystem::remove_all(pages_dir, ec);
    return Finish(st, progress);
  }
  ctx.SetStat("book_pages", plan.pages);
  meta.emplace_back("nimbus_book_depth", int64_t(plan.depth));
  meta.emplace_back("nimbus_book_pages", int64_t(plan.pages));
  return Finish(WriteDensityVdb(main_path, sum, job.frame, job.density, meta), progress);
}

}  // namespace nimbus::server
