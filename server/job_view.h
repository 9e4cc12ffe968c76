// Conversions between job store records and the wire's nimbus.v1.Job.
#pragma once

#include "nimbus/v1/nimbus_service.pb.h"
#include "server/job_store.h"

namespace nimbus::server {

v1::JobState ToProto(JobState s);
std::optional<JobState> FromProto(v1::JobState s);
/// The wire view of a record; the spec is parsed back in only if asked for.
v1::Job ToProto(const JobRecord& r, bool with_spec);
TimeMs NowMs();

/// A registry row's wire view; lost when its last heartbeat is more than
/// `lease_ms` before `now`.
v1::Worker ToProto(const WorkerInfo& w, TimeMs now, TimeMs lease_ms);
v1::JobEvent ToProto(const JobEvent& e);

}  // namespace nimbus::server
