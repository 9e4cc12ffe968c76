// Jobs with real committed results, for tests of what reads them back
// (retention, the embedded server's export): a job store and a result
// store in one folder (and a fixture with both), and a job run to
// success with given bytes.
// Header-only: the server library comes from the test executable.
#pragma once

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <memory>
#include <string>

#include "absl/status/statusor.h"
#include "core/base/status_macros.h"
#include "server/job_store.h"
#include "server/result_store.h"
#include "tests/support/test_util.h"

namespace nimbus::testing {

struct LocalStores {
  std::unique_ptr<server::JobStore> jobs;
  std::unique_ptr<server::ResultStore> results;
};

/// A SQLite job store (dir/jobs.db) and a result store (dir/results).
inline absl::StatusOr<LocalStores> OpenLocalStores(const std::filesystem::path& dir) {
  LocalStores s;
  NIMBUS_ASSIGN_OR_RETURN(s.jobs, server::OpenSqliteJobStore((dir / "jobs.db").string()));
  NIMBUS_ASSIGN_OR_RETURN(s.results, server::OpenLocalResultStore(dir / "results"));
  return s;
}

/// Claims the oldest queued job as worker "w" and completes it at `end`
/// with `bytes` committed as its result; returns its id.
inline absl::StatusOr<std::string> SucceedNext(server::JobStore& jobs, server::ResultStore& results,
                                               const std::string& bytes, server::TimeMs end) {
  NIMBUS_ASSIGN_OR_RETURN(auto claimed, jobs.ClaimNext("w", end, 1000));
  if (!claimed) return absl::FailedPreconditionError("no queued job to run");
  const std::string id = claimed->id;
  std::ofstream(results.ScratchPath(id), std::ios::binary) << bytes;
  NIMBUS_ASSIGN_OR_RETURN(const server::StoredResult stored,
                          results.Commit(id, results.ScratchPath(id)));
  server::Completion c;
  c.result_key = stored.key;
  c.result_size = stored.size;
  c.result_sha256 = stored.sha256;
  NIMBUS_RETURN_IF_ERROR(jobs.Complete(id, "w", c, end));
  return id;
}

/// A fixture holding both stores of OpenLocalStores in a fresh folder.
class LocalStoresTest : public ::testing::Test {
 protected:
  void SetUp() override {
    auto stores = OpenLocalStores(dir_.path());
    ASSERT_TRUE(stores.ok()) << stores.status();
    store_ = std::move(stores->jobs);
    results_ = std::move(stores->results);
  }

  TempDir dir_;
  std::unique_ptr<server::JobStore> store_;
  std::unique_ptr<server::ResultStore> results_;
};

}  // namespace nimbus::testing
