// A JobContext that records what a runner reports, for runner tests
// without a server. Header-only so tests/support needs no server link.
#pragma once

#include <filesystem>
#include <map>
#include <string>
#include <vector>

#include "server/job_runner.h"
#include "tests/support/test_util.h"

namespace nimbus::testing {

class FakeJobContext : public server::JobContext {
 public:
  /// Writes the result to `out`, or into a temp dir when empty.
  explicit FakeJobContext(std::filesystem::path out = {}) : out_(std::move(out)) {
    if (out_.empty()) out_ = dir_ / "result.vdb";
  }

  const std::string& job_id() const override { return id_; }
  int threads() const override { return threads_; }
  uint64_t memory_budget() const override { return memory_budget_; }
  Interrupter* interrupter() override { return interrupter_; }
  absl::Status ReportProgress(const server::JobProgress& p) override {
    // Phases never go back; within one, done never decreases and stays
    // within the total.
    if (!progress.empty() && (p.phase < progress.back().phase ||
                              (p.phase == progress.back().phase && p.done < progress.back().done)))
      progress_ordered = false;
    if (p.done > p.total) progress_ordered = false;
    progress.push_back({p.phase, p.done, p.total, std::string(p.unit)});
    return absl::OkStatus();
  }
  void MaybePublishPreview(const std::vector<const CountGrid*>&, const GridFrame&,
                           const DensityOptions&, uint64_t) override {
    ++previews;
  }
  void SetStat(const std::string& key, uint64_t value) override { stats[key] = value; }
  void AddWarning(const std::string& w) override { warnings.push_back(w); }
  std::filesystem::path ResultScratchPath() override { return out_; }
  Metadata BaseMetadata() const override { return {}; }

  /// The last report of `phase`, or a zero one.
  struct Report {
    server::JobPhase phase;
    uint64_t done = 0, total = 0;
    std::string unit;
  };
  Report Last(server::JobPhase phase) const {
    for (auto it = progress.rbegin(); it != progress.rend(); ++it)
      if (it->phase == phase) return *it;
    return {phase, 0, 0, ""};
  }
  std::filesystem::path result() const { return out_; }

  std::map<std::string, uint64_t> stats;
  std::vector<std::string> warnings;
  std::vector<Report> progress;
  bool progress_ordered = true;
  int previews = 0;
  int threads_ = 2;
  uint64_t memory_budget_ = uint64_t{16} << 30;
  Interrupter* interrupter_ = nullptr;

 private:
  std::string id_ = "job";
  TempDir dir_;
  std::filesystem::path out_;
};

}  // namespace nimbus::testing
