// Result files that no job owns: what a lost or replaced job database
// leaves behind in the results folder.
//
//   auto unknown = FindUnknownResults(*store, results_dir, 10'000);
//   if (unknown.ok() && !unknown->ids.empty()) spdlog::warn(...);
#pragma once

#include <cstddef>
#include <filesystem>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "server/job_store.h"

namespace nimbus::server {

struct UnknownResults {
  /// Job ids of the result files (`<id>.vdb`) the store has no job for,
  /// in name order.
  std::vector<std::string> ids;
  /// Result files looked at; at most the limit given.
  size_t checked = 0;
};

/// Looks up the job of every `<id>.vdb` directly in `results_dir` (at most
/// `max_files` of them) and returns those `store` does not know. Reads
/// only names, never the files; a missing folder has none.
absl::StatusOr<UnknownResults> FindUnknownResults(JobStore& store,
                                                  const std::filesystem::path& results_dir,
                                                  size_t max_files);

}  // namespace nimbus::server
