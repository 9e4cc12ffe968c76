// Watching a job while fetching the first result file it lists before it
// finishes: the check, shared by the e2e tests of every kind that writes
// frames or pages, that files stream while the job runs. Header-only, so
// tests/support needs no client link.
#pragma once

#include <filesystem>
#include <string>

#include "absl/status/statusor.h"
#include "client/nimbus_client.h"

namespace nimbus::testing {

/// @brief What WatchFetchingFirstFile saw.
struct EarlyFetch {
  int fetched_while_running = 0;
  std::string name;    // the file fetched
  std::string sha256;  // as listed at that moment
};

/// Watches job `id` to its end. The first time an update shows the job
/// running with at least one result file, fetches files(0) to `to`.
inline absl::StatusOr<v1::Job> WatchFetchingFirstFile(client::NimbusClient& client,
                                                      const std::string& id,
                                                      const std::filesystem::path& to,
                                                      EarlyFetch& early) {
  return client.Watch(id, {}, [&](const v1::WatchJobResponse& r) {
    if (r.job().state() != v1::JOB_STATE_RUNNING || r.job().result().files_size() == 0 ||
        early.fetched_while_running > 0)
      return;
    const v1::ResultFile& f = r.job().result().files(0);
    if (!client.Fetch(id, to, f.file_name()).ok()) return;
    early.name = f.file_name();
    early.sha256 = f.sha256();
    ++early.fetched_while_running;
  });
}

}  // namespace nimbus::testing
