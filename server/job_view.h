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

}  // namespace nimbus::server
