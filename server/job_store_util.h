// Pieces both job stores (SQLite and PostgreSQL) share, so that listings
// page and bound alike whichever store a server uses.
#pragma once

#include <cstdint>
#include <string>
#include <tuple>

#include "absl/status/status.h"
#include "server/job_store.h"

namespace nimbus::server {

/// The page token is opaque to clients; inside it is the (create_time, id)
/// keyset cursor of the last row returned, so pages stay stable while new
/// jobs arrive (they sort before the cursor).
std::string EncodePageToken(TimeMs create_time, const std::string& id);
/// INVALID_ARGUMENT naming the token when it was not made by EncodePageToken.
absl::Status DecodePageToken(const std::string& token, TimeMs* create_time, std::string* id);

/// What a record adds to a ListJobs response, about: the view's text (the
/// error twice: as error and as status.message) plus fixed fields, counted
/// with the bounds the view applies, so a stored giant does not end a page.
uint64_t ViewBytes(const JobRecord& r);

/// OK for kMinPriority..kMaxPriority; INVALID_ARGUMENT naming `priority`
/// otherwise.
absl::Status CheckPriority(int priority);

/// Whether a claim candidate of one owner goes before another's under the
/// fair-share rule (docs/operator_guide.md "Claim order"): fewer RUNNING
/// jobs, then the older last claim (0: never claimed, first of all), then
/// the older job (create time, then insertion order).
struct OwnerTurn {
  uint64_t running = 0;
  int64_t last_claim = 0;
  TimeMs create_time = 0;
  int64_t seq = 0;
  std::string job_id;
  bool operator<(const OwnerTurn& o) const {
    return std::tie(running, last_claim, create_time, seq) <
           std::tie(o.running, o.last_claim, o.create_time, o.seq);
  }
};

/// The event log entry of a recorded end (Complete writes it in its own
/// transaction): succeeded (size, sha256), failed or cancelled (code,
/// message), naming the worker.
JobEvent EndEvent(const std::string& worker_id, const Completion& c, TimeMs now);

/// The event log entry Create writes for a job with `submitted_by`: by,
/// priority, retried_from and cached_from (the last two empty unless set).
JobEvent SubmittedEvent(const NewJob& job, TimeMs now);

/// The event log entry RequestCancel writes for a QUEUED job it ends:
/// `cancelled` with `by`, the caller who asked.
JobEvent QueuedCancelEvent(const std::string& by, TimeMs now);

/// Milliseconds since the epoch, for the few store operations that take no
/// `now` (start-up recovery, cascades): the honest end time there.
TimeMs WallClockMs();

/// `url` without its password ("postgresql://user:***@host/db"), for
/// messages and logs.
std::string RedactUrl(const std::string& url);

}  // namespace nimbus::server
