// The seam between the worker pool and the generators. A runner turns one
// validated job into result files; the JobContext gives it progress,
// previews, cancellation and where to write. One runner per generator
// (chaos_game_runner.cc, ...), so generators grow without touching the pool.
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "core/chaos/chaos_game.h"
#include "core/grid/count_grid.h"
#include "core/base/geometry.h"
#include "core/base/interrupter.h"
#include "core/io/vdb_io.h"
#include "nimbus/v1/spec.pb.h"
#include "proto/spec_convert.h"

namespace nimbus::server {

/// @brief What the worker offers a running job. Called from the worker
/// thread only (the interrupter is also polled by engine threads).
class JobContext {
 public:
  virtual ~JobContext() = default;
  virtual const std::string& job_id() const = 0;
  /// Engine threads this job may use.
  virtual int threads() const = 0;
  /// Stops on cancel or shutdown; pass it to every core computation.
  virtual Interrupter* interrupter() = 0;
  /// Publishes progress to watchers and keeps the job's lease alive. Call
  /// every ~0.2 s. Returns AbortedError if the claim was lost.
  virtual absl::Status ReportProgress(uint64_t done, uint64_t total) = 0;
  /// Builds and publishes previews if a watcher is due one. `parts` are
  /// summed (per-thread partial counts).
  virtual void MaybePublishPreview(const std::vector<const CountGrid*>& parts,
                                   const GridFrame& frame, const DensityOptions& density,
                                   uint64_t done) = 0;
  virtual void SetStat(const std::string& key, uint64_t value) = 0;
  virtual void AddWarning(const std::string& warning) = 0;
  /// Where the job's main result (one .vdb) must be written.
  virtual std::filesystem::path ResultScratchPath() = 0;
  /// Metadata every result grid carries (seed is added by the runner).
  virtual Metadata BaseMetadata() const = 0;
};

/// Publishes a chaos game's counters as job stats and warns when many
/// points went non-finite or fell outside the grid.
void ReportChaosGameStats(const ChaosGameStats& stats, JobContext& ctx);

/// Runs a chaos-game job (plain or recurrent IFS) into ResultScratchPath().
absl::Status RunChaosGameJob(const spec::ConvertedJob& job, JobContext& ctx);
/// Runs a recurrent-IFS (IFS matrix) job into ResultScratchPath().
absl::Status RunIfsMatrixJob(const spec::ConvertedJob& job, JobContext& ctx);
/// Runs a set-IFS job (random iteration or book) into ResultScratchPath().
absl::Status RunSetIfsJob(const spec::ConvertedJob& job, JobContext& ctx);

}  // namespace nimbus::server
