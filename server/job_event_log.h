// The job event log: a bounded, ordered log of structured events per job,
// kept in the job store (docs/operator_guide.md "Job event log"): what
// happened to a job, whichever replica ran it. Beside the queue: the store
// implements it on its own table.
#pragma once

#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"

namespace nimbus::server {

/// Events kept per job: appending one more drops the oldest.
inline constexpr int64_t kMaxEventsPerJob = 1000;
/// Bytes of one field value kept (longer ones are cut, BoundText).
inline constexpr size_t kMaxEventFieldBytes = 1024;

/// @brief One event: its kind (the list in docs/operator_guide.md "Job event
/// log": "submitted", "claimed", "lease_lost", "succeeded", ...) and named
/// fields.
struct JobEvent {
  /// 1, 2, ... per job, in the order appended (set by AppendEvent).
  int64_t seq = 0;
  /// Milliseconds since the Unix epoch.
  int64_t time = 0;
  std::string kind;
  std::vector<std::pair<std::string, std::string>> fields;
};

struct JobEventPage {
  /// Oldest first.
  std::vector<JobEvent> events;
  /// The seq to ask for after, for the next page; 0 when this is the last.
  int64_t next_after = 0;
  /// Events of the job dropped to keep the newest kMaxEventsPerJob.
  int64_t dropped = 0;
};

/// @brief Per-job event logs. All methods are thread-safe. A store without
/// a log keeps none (the defaults).
class JobEventLog {
 public:
  virtual ~JobEventLog() = default;

  /// Appends `event` (its seq is assigned) to `job_id`'s log, dropping the
  /// oldest beyond kMaxEventsPerJob. Field names and values are stored
  /// bounded.
  virtual absl::Status AppendEvent(const std::string& job_id, const JobEvent& event) {
    (void)job_id, (void)event;
    return absl::OkStatus();
  }
  /// Up to `limit` events of `job_id` with seq > `after`, oldest first.
  virtual absl::StatusOr<JobEventPage> ListEvents(const std::string& job_id, int64_t after,
                                                  int limit) {
    (void)job_id, (void)after, (void)limit;
    return JobEventPage();
  }
};

/// Appends an event stamped now; a failure is logged (spdlog), never
/// returned: the log records what happened, it never stops it.
void LogJobEvent(JobEventLog& log, const std::string& job_id, const char* kind,
                 std::vector<std::pair<std::string, std::string>> fields);

/// Fields as stored: "name=value" lines (newlines in values become spaces,
/// values bounded by kMaxEventFieldBytes).
std::string EncodeEventFields(const std::vector<std::pair<std::string, std::string>>& fields);
std::vector<std::pair<std::string, std::string>> DecodeEventFields(const std::string& text);

}  // namespace nimbus::server
