#include "server/job_view.h"

#include <algorithm>
#include <chrono>

#include "absl/strings/str_split.h"
#include "proto/result_files.h"
#include "server/bounded_text.h"

namespace nimbus::server {

namespace {
void SetTime(TimeMs ms, google::protobuf::Timestamp* t) {
  t->set_seconds(ms / 1000);
  t->set_nanos(int32_t(ms % 1000) * 1000000);
}
}  // namespace

TimeMs NowMs() {
  return std::chrono::duration_cast<std::chrono::milliseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}

v1::JobState ToProto(JobState s) {
  switch (s) {
    case JobState::kQueued: return v1::JOB_STATE_QUEUED;
    case JobState::kRunning: return v1::JOB_STATE_RUNNING;
    case JobState::kSucceeded: return v1::JOB_STATE_SUCCEEDED;
    case JobState::kFailed: return v1::JOB_STATE_FAILED;
    case JobState::kCancelled: return v1::JOB_STATE_CANCELLED;
  }
  return v1::JOB_STATE_UNSPECIFIED;
}

std::optional<JobState> FromProto(v1::JobState s) {
  switch (s) {
    case v1::JOB_STATE_QUEUED: return JobState::kQueued;
    case v1::JOB_STATE_RUNNING: return JobState::kRunning;
    case v1::JOB_STATE_SUCCEEDED: return JobState::kSucceeded;
    case v1::JOB_STATE_FAILED: return JobState::kFailed;
    case v1::JOB_STATE_CANCELLED: return JobState::kCancelled;
    default: return std::nullopt;
  }
}

v1::Job ToProto(const JobRecord& r, bool with_spec) {
  v1::Job j;
  j.set_id(r.id);
  // Bounded again here: stores written before the bounds may hold giants.
  const std::string name = BoundText(r.name, kMaxJobNameBytes);
  const std::string error = BoundText(r.error, kMaxErrorBytes);
  j.set_name(name);
  j.set_state(ToProto(r.state));
  if (with_spec) j.mutable_spec()->ParseFromString(r.spec);
  SetTime(r.create_time, j.mutable_create_time());
  if (r.start_time) SetTime(r.start_time, j.mutable_start_time());
  if (r.end_time) SetTime(r.end_time, j.mutable_end_time());
  j.mutable_progress()->set_done(r.progress_done);
  j.mutable_progress()->set_total(r.progress_total);
  j.set_error(error);
  if (r.state == JobState::kFailed || r.state == JobState::kCancelled) {
    // Records written before codes were stored have none: CANCELLED for a
    // cancelled job, UNKNOWN for a failed one.
    int code = r.error_code;
    if (code == 0) code = r.state == JobState::kCancelled ? 1 : 2;
    j.mutable_status()->set_code(code);
    j.mutable_status()->set_message(error);
  }
  // Only while it still matters: a finished job has stopped either way.
  j.set_cancel_requested(r.cancel_requested && !IsTerminal(r.state));
  if (r.state == JobState::kSucceeded) {
    j.mutable_result()->set_size_bytes(r.result_size);
    j.mutable_result()->set_sha256(r.result_sha256);
    v1::JobSpec spec;
    if (!with_spec) spec.ParseFromString(r.spec);
    j.mutable_result()->set_file_name(
        name + spec::MainResultExtension(with_spec ? j.spec() : spec));
  }
  j.set_attempts(r.attempts);
  if (r.state == JobState::kRunning) j.set_worker(r.worker_id);
  const std::string warnings = BoundText(r.warnings, kMaxWarningsBytes);
  for (auto w : absl::StrSplit(warnings, '\n', absl::SkipEmpty())) j.add_warnings(std::string(w));
  j.set_estimated_memory_bytes(r.estimated_memory_bytes);
  j.set_owner(r.owner);
  j.set_pinned(r.pinned);
  if (r.result_expire_time) SetTime(r.result_expire_time, j.mutable_result_expire_time());
  // Result cache and sharded jobs (docs/result_cache.md, docs/sharding.md).
  j.set_cached_from(r.cached_from);
  if (r.shard_count > 1 && r.parent_id.empty()) {
    j.set_shards(r.shard_count);
    j.set_shards_succeeded(r.shard_count - std::min(r.shards_pending, r.shard_count));
  }
  return j;
}

}  // namespace nimbus::server
