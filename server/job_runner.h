// @brief The seam between the worker pool and the engines. A runner turns
// one JobPlan into result files; the JobContext gives it progress,
// previews, cancellation and where to write. One RunKind overload per job
// kind (chaos_game_runner.cc, ...), selected by std::visit in RunJobPlan, so
// a kind without a runner does not compile. Runners drive their engine
// through the one loop of server/job_driver.h.
#pragma once

#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/base/interrupter.h"
#include "core/grid/count_grid.h"
#include "core/io/vdb_io.h"
#include "core/plan/job_plan.h"

namespace nimbus::server {

/// What a job is doing; the phases follow each other in this order.
enum class JobPhase { kPreparing, kIterating, kWriting };

/// @brief Progress of the current phase, in its own units.
struct JobProgress {
  JobPhase phase = JobPhase::kPreparing;
  uint64_t done = 0;
  uint64_t total = 0;
  std::string_view unit;
};

/// @brief What the worker offers a running job. Called from the worker
/// thread only (the interrupter is also polled by engine threads).
class JobContext {
 public:
  virtual ~JobContext() = default;
  virtual const std::string& job_id() const = 0;
  /// Engine threads this job may use (the size of its task arena).
  virtual int threads() const = 0;
  /// Bytes the engines may hold before they stop with RESOURCE_EXHAUSTED
  /// (the run-time safety net behind memory admission); 0 = no limit.
  virtual uint64_t memory_budget() const = 0;
  /// Stops on cancel or shutdown; pass it to every core computation.
  virtual Interrupter* interrupter() = 0;
  /// Publishes progress to watchers and keeps the job's lease alive. Call
  /// every ~0.2 s. Returns AbortedError if the claim was lost.
  virtual absl::Status ReportProgress(const JobProgress& progress) = 0;
  /// Whether a watcher (or a parent job) wants this job's previews at all:
  /// engines gather partial counts for MaybePublishPreview only then.
  virtual bool WantsPreview() { return true; }
  /// Builds and publishes previews if a watcher is due one. `parts` are
  /// summed (per-thread partial counts).
  virtual void MaybePublishPreview(const std::vector<const CountGrid*>& parts,
                                   const GridFrame& frame, const DensityOptions& density,
                                   uint64_t done) = 0;
  /// @brief A picture job's preview: a 2D density grid (one voxel per
  /// preview pixel) and its PNG.
  struct PicturePreview {
    CountGrid counts{Int3{1, 1, 1}};
    GridFrame frame;
    std::string png;
  };
  /// Like MaybePublishPreview for a picture: `make(resolution)` builds the
  /// preview for a watcher that asked for grids of at most `resolution`
  /// voxels per axis. Only called when one is due. Default: none.
  virtual void MaybePublishPicturePreview(
      const std::function<absl::StatusOr<PicturePreview>(int resolution)>& make, uint64_t done) {
    (void)make, (void)done;
  }
  virtual void SetStat(const std::string& key, uint64_t value) = 0;
  virtual void AddWarning(const std::string& warning) = 0;
  /// Where the job's main result (one .vdb) must be written; further files
  /// (frames, pages) go to ExtraFilesDir() of it.
  virtual std::filesystem::path ResultScratchPath() = 0;
  /// Metadata every result grid carries (spec hash, version).
  virtual Metadata BaseMetadata() const = 0;
  /// Pokes on this (jelly) job that take effect at `frame`: pokes not yet
  /// given a frame get this one, durably, so a restarted attempt replays
  /// them at the same frames. Called between frames, in frame order.
  virtual absl::StatusOr<std::vector<JellyPoke>> TakePokes(uint64_t frame) {
    (void)frame;
    return std::vector<JellyPoke>{};
  }
};

// One runner per job kind. Each writes ResultScratchPath() (and further
// files) and returns CANCELLED when interrupted.
absl::Status RunKind(const JobPlan& plan, const ChaosGamePlan& kind, JobContext& ctx);
absl::Status RunKind(const JobPlan& plan, const IfsMatrixPlan& kind, JobContext& ctx);
absl::Status RunKind(const JobPlan& plan, const SetIfsPlan& kind, JobContext& ctx);
absl::Status RunKind(const JobPlan& plan, const FractalFieldPlan& kind, JobContext& ctx);
absl::Status RunKind(const JobPlan& plan, const JellyPlan& kind, JobContext& ctx);
absl::Status RunKind(const JobPlan& plan, const ExplorePlan& kind, JobContext& ctx);

/// Runs `plan` with the runner of its kind.
absl::Status RunJobPlan(const JobPlan& plan, JobContext& ctx);

}  // namespace nimbus::server
