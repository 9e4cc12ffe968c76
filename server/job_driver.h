// @brief The one job-driving loop every runner uses: phases and progress,
// rounds with fixed checkpoints, previews between rounds, cancellation
// (including a lost claim), and writing the result and numbered frames.
//
//   JobDriver d(plan, ctx);
//   NIMBUS_RETURN_IF_ERROR(d.BeginPhase(JobPhase::kIterating, plan.work.total, plan.work.unit));
//   JobDriver::Rounds r;
//   r.total = plan.work.total;
//   r.advance = [&](uint64_t target) { return engine.RunTo(target); };
//   r.finished = [&] { return engine.done(); };
//   NIMBUS_RETURN_IF_ERROR(d.RunRounds(r));
//   return d.WriteResult(counts, d.Metadata().Add(meta_key::kSeed, seed).Build());
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include "absl/status/statusor.h"
#include "core/chaos/chaos_game.h"
#include "core/io/metadata_keys.h"
#include "server/job_runner.h"

namespace nimbus::server {

/// @brief Builds a result's metadata on top of the job's base metadata,
/// with the named keys of core/io/metadata_keys.h.
class MetadataBuilder {
 public:
  explicit MetadataBuilder(Metadata base) : meta_(std::move(base)) {}
  MetadataBuilder& Add(std::string_view key, MetaValue value);
  /// A chaos game's iterations and bad-point counters.
  MetadataBuilder& ChaosStats(const ChaosGameStats& stats);
  const Metadata& Build() const { return meta_; }

 private:
  Metadata meta_;
};

class JobDriver {
 public:
  JobDriver(const JobPlan& plan, JobContext& ctx);

  const JobPlan& plan() const { return plan_; }
  JobContext& ctx() { return ctx_; }

  /// Starts a phase; progress counts its units from 0 and is published at
  /// once. Returns ABORTED when the job's claim was lost.
  absl::Status BeginPhase(JobPhase phase, uint64_t total, std::string unit);
  /// Publishes `done` units of the current phase if 0.2 s passed since the
  /// last report, or at once when `force`.
  absl::Status Progress(uint64_t done, bool force = false);

  /// Cancellation for core computations. Polls made on the worker thread
  /// call the hook set by FollowPolls (progress from inside an engine).
  Interrupter* interrupter() { return &interrupter_; }
  /// `hook(done, total)` runs for polls on the worker thread; null: none.
  void FollowPolls(std::function<void(uint64_t done, uint64_t total)> hook);
  /// A lost claim seen by a poll hook, or the status to return.
  absl::Status Check(absl::Status status) const;

  /// @brief A run in rounds of ~0.2 s. `advance(target)` runs the engine
  /// until at least `target` units are done (whole work units) and returns
  /// the units done. Rounds end on multiples of `checkpoint_every` (0:
  /// none), where `at_checkpoint(done)` may stop the run early: where a job
  /// stops depends on the spec only, never on timing or threads.
  struct Rounds {
    uint64_t offset = 0;  // units done before these rounds (progress, previews)
    uint64_t total = 0;   // units of these rounds
    uint64_t min_step = 1;
    uint64_t first_step = 0;  // 0: min_step
    /// Steps are rounded up to a multiple of this (0: not rounded): whole
    /// chunks for every thread, so no thread waits out a round's last chunk.
    uint64_t step_multiple = 0;
    uint64_t checkpoint_every = 0;
    std::function<absl::StatusOr<uint64_t>(uint64_t target)> advance;
    std::function<bool()> finished;
    std::function<bool(uint64_t done)> at_checkpoint;  // true: stop now
    std::function<std::vector<const CountGrid*>()> parts;  // preview source
    /// Publishes a preview itself instead (pictures); gets the units done.
    std::function<void(uint64_t done)> preview;
  };
  absl::Status RunRounds(const Rounds& rounds);

  /// Publishes a preview of `parts` if a watcher is due one.
  void Preview(const std::vector<const CountGrid*>& parts, uint64_t done);

  /// Metadata builder starting from the job's base metadata.
  MetadataBuilder Metadata() const { return MetadataBuilder(ctx_.BaseMetadata()); }
  /// Writes the main result in the writing phase.
  /// `fields`: further Vec3f grids (a jelly's velocity "v").
  absl::Status WriteResult(const CountGrid& counts, const nimbus::Metadata& meta,
                           const std::vector<Vec3Field>& fields = {});
  /// Writes frame `index` (0-based) as NAME.0001.vdb (index + 1) beside the
  /// result; a listed frame is complete and can be fetched while the job
  /// runs. The first call removes frames a previous attempt left.
  absl::Status WriteFrame(uint64_t index, const CountGrid& counts, const nimbus::Metadata& meta,
                          const std::vector<Vec3Field>& fields = {});
  /// The same for a computed float volume (fractal fields).
  absl::Status WriteResult(const FloatVolume& volume, const nimbus::Metadata& meta);
  absl::Status WriteFrame(uint64_t index, const FloatVolume& volume, const nimbus::Metadata& meta);
  /// Removes every frame written so far (a failed or cancelled run).
  void DiscardFrames();
  /// Where a further result file `name` goes (beside the frames), listed
  /// and fetchable with the result.
  absl::StatusOr<std::filesystem::path> ExtraFilePath(const std::string& name);

 private:
  class DriverInterrupter : public Interrupter {
   public:
    explicit DriverInterrupter(JobDriver* d) : d_(d) {}
    bool WasInterrupted(uint64_t done, uint64_t total) override;

   private:
    JobDriver* d_;
  };
  std::filesystem::path FramesDir();
  absl::Status PrepareFramesDir();

  const JobPlan& plan_;
  JobContext& ctx_;
  DriverInterrupter interrupter_{this};
  const std::thread::id owner_ = std::this_thread::get_id();
  std::function<void(uint64_t, uint64_t)> poll_hook_;
  JobPhase phase_ = JobPhase::kPreparing;
  uint64_t phase_total_ = 0;
  std::string unit_;
  std::chrono::steady_clock::time_point last_report_;
  absl::Status lost_claim_;
  bool frames_ready_ = false;
};

/// "NAME.0001.vdb" for index 0.
std::string FrameFileName(const std::string& name, uint64_t index);

}  // namespace nimbus::server
