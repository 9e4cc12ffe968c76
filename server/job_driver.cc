#include "server/job_driver.h"

#include <algorithm>
#include <cstdio>
#include <system_error>

#include "absl/strings/str_cat.h"
#include "core/base/status_macros.h"
#include "server/result_store.h"

namespace nimbus::server {

namespace {
using Clock = std::chrono::steady_clock;
// Between progress reports and rounds: watchers see ~5 updates a second.
constexpr auto kReportInterval = std::chrono::milliseconds(200);
constexpr double kRoundSeconds = 0.2;

// Records the result write's wall time as the job stat write_ms, so the
// share of a job spent writing its VDB is visible (GetJob's stats).
class WriteTimer {
 public:
  explicit WriteTimer(JobContext& ctx) : ctx_(ctx), start_(Clock::now()) {}
  ~WriteTimer() {
    ctx_.SetStat("write_ms", uint64_t(std::chrono::duration<double, std::milli>(
                                          Clock::now() - start_).count()));
  }

 private:
  JobContext& ctx_;
  Clock::time_point start_;
};
}  // namespace

MetadataBuilder& MetadataBuilder::Add(std::string_view key, MetaValue value) {
  meta_.emplace_back(std::string(key), std::move(value));
  return *this;
}

MetadataBuilder& MetadataBuilder::ChaosStats(const ChaosGameStats& stats) {
  Add(meta_key::kIterations, int64_t(stats.iterations_done));
  Add(meta_key::kOutside, int64_t(stats.outside));
  return Add(meta_key::kReseeded, int64_t(stats.reseeded));
}

JobDriver::JobDriver(const JobPlan& plan, JobContext& ctx) : plan_(plan), ctx_(ctx) {}

absl::Status JobDriver::BeginPhase(JobPhase phase, uint64_t total, std::string unit) {
  phase_ = phase;
  phase_total_ = total;
  unit_ = std::move(unit);
  return Progress(0, true);
}

absl::Status JobDriver::Progress(uint64_t done, bool force) {
  if (!lost_claim_.ok()) return lost_claim_;
  const auto now = Clock::now();
  if (!force && now - last_report_ < kReportInterval) return absl::OkStatus();
  last_report_ = now;
  absl::Status st =
      ctx_.ReportProgress({phase_, std::min(done, phase_total_), phase_total_, unit_});
  if (absl::IsAborted(st)) lost_claim_ = st;
  return st;
}

void JobDriver::FollowPolls(std::function<void(uint64_t, uint64_t)> hook) {
  poll_hook_ = std::move(hook);
}

absl::Status JobDriver::Check(absl::Status status) const {
  return lost_claim_.ok() ? status : lost_claim_;
}

bool JobDriver::DriverInterrupter::WasInterrupted(uint64_t done, uint64_t total) {
  if (!d_->lost_claim_.ok()) return true;
  if (OrNull(d_->ctx_.interrupter()).WasInterrupted(done, total)) return true;
  // Engines poll from their worker threads too; only the job's own thread
  // may publish.
  if (d_->poll_hook_ && std::this_thread::get_id() == d_->owner_) d_->poll_hook_(done, total);
  return !d_->lost_claim_.ok();
}

absl::Status JobDriver::RunRounds(const Rounds& r) {
  uint64_t step = std::max<uint64_t>(r.first_step ? r.first_step : r.min_step, 1);
  uint64_t next_check = r.checkpoint_every;
  uint64_t done = 0;
  while (!r.finished()) {
    const auto round_start = Clock::now();
    uint64_t target = done + step;
    if (r.checkpoint_every > 0) target = std::min(target, next_check);
    const uint64_t before = done;
    NIMBUS_ASSIGN_OR_RETURN(done, r.advance(target));
    const double round_s =
        std::max(1e-4, std::chrono::duration<double>(Clock::now() - round_start).count());
    step = std::clamp<uint64_t>(uint64_t(double(done - before) * kRoundSeconds / round_s),
                                std::max<uint64_t>(r.min_step, 1), std::max<uint64_t>(r.total, 1));
    if (r.step_multiple > 1) step = (step + r.step_multiple - 1) / r.step_multiple * r.step_multiple;
    NIMBUS_RETURN_IF_ERROR(Progress(r.offset + done, true));
    if (r.checkpoint_every > 0 && done >= next_check && !r.finished()) {
      next_check += r.checkpoint_every;
      if (r.at_checkpoint && r.at_checkpoint(done)) break;
    }
    // Partial counts may cost a pass (ChaosGame::partial_counts): gathered
    // only for a preview someone wants.
    if (r.preview)
      r.preview(r.offset + done);
    else if (r.parts && ctx_.WantsPreview())
      Preview(r.parts(), r.offset + done);
  }
  return absl::OkStatus();
}

void JobDriver::Preview(const std::vector<const CountGrid*>& parts, uint64_t done) {
  ctx_.MaybePublishPreview(parts, plan_.frame, plan_.density, done);
}

absl::Status JobDriver::WriteResult(const CountGrid& counts, const nimbus::Metadata& meta,
                                    const std::vector<Vec3Field>& fields) {
  NIMBUS_RETURN_IF_ERROR(BeginPhase(JobPhase::kWriting, 1, "files"));
  WriteTimer timer(ctx_);
  NIMBUS_RETURN_IF_ERROR(
      WriteDensityVdb(ctx_.ResultScratchPath(), counts, plan_.frame, plan_.density, meta, fields));
  if (plan_.density.raw_counts == RawCounts::kInteger) {
    // Exact counts in a further file: readers that cannot open Int64 grids
    // still open the result.
    NIMBUS_ASSIGN_OR_RETURN(std::filesystem::path side, ExtraFilePath(plan_.name + ".counts.vdb"));
    NIMBUS_RETURN_IF_ERROR(WriteIntegerCountsVdb(side, counts, plan_.frame, plan_.density, meta));
  }
  return Progress(1, true);
}

std::filesystem::path JobDriver::FramesDir() { return ExtraFilesDir(ctx_.ResultScratchPath()); }

absl::Status JobDriver::WriteFrame(uint64_t index, const CountGrid& counts,
                                   const nimbus::Metadata& meta,
                                   const std::vector<Vec3Field>& fields) {
  NIMBUS_RETURN_IF_ERROR(PrepareFramesDir());
  const std::filesystem::path dir = FramesDir();
  // WriteDensityVdb renames a finished file into place, so a listed frame
  // is always complete.
  return WriteDensityVdb(dir / FrameFileName(plan_.name, index), counts, plan_.frame,
                         plan_.density, meta, fields);
}

absl::Status JobDriver::WriteResult(const FloatVolume& volume, const nimbus::Metadata& meta) {
  NIMBUS_RETURN_IF_ERROR(BeginPhase(JobPhase::kWriting, 1, "files"));
  WriteTimer timer(ctx_);
  NIMBUS_RETURN_IF_ERROR(
      WriteFloatVolumeVdb(ctx_.ResultScratchPath(), volume, meta, plan_.density.conventions));
  return Progress(1, true);
}

absl::Status JobDriver::WriteFrame(uint64_t index, const FloatVolume& volume,
                                   const nimbus::Metadata& meta) {
  NIMBUS_RETURN_IF_ERROR(PrepareFramesDir());
  return WriteFloatVolumeVdb(FramesDir() / FrameFileName(plan_.name, index), volume, meta,
                             plan_.density.conventions);
}

absl::Status JobDriver::PrepareFramesDir() {
  if (frames_ready_) return absl::OkStatus();
  const std::filesystem::path dir = FramesDir();
  std::error_code ec;
  std::filesystem::remove_all(dir, ec);  // a previous attempt's files
  std::filesystem::create_directories(dir, ec);
  if (ec)
    return absl::InternalError(absl::StrCat("cannot create the result files folder: ", ec.message()));
  frames_ready_ = true;
  return absl::OkStatus();
}

absl::StatusOr<std::filesystem::path> JobDriver::ExtraFilePath(const std::string& name) {
  NIMBUS_RETURN_IF_ERROR(PrepareFramesDir());
  return FramesDir() / name;
}

void JobDriver::DiscardFrames() {
  std::error_code ec;
  std::filesystem::remove_all(FramesDir(), ec);
}

std::string FrameFileName(const std::string& name, uint64_t index) {
  char buf[32];
  std::snprintf(buf, sizeof buf, ".%04llu.vdb", static_cast<unsigned long long>(index + 1));
  return name + buf;
}

}  // namespace nimbus::server
