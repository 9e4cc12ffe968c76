// @brief Ownership and quota checks of the service: which jobs and assets a
// principal may see, and whether it may store more. Runs on the admission
// thread or the blocking executor (it reads the store and the asset folder).
#pragma once

#include <optional>
#include <string>

#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "nimbus/v1/spec.pb.h"
#include "server/asset_store.h"
#include "server/auth.h"
#include "server/job_store.h"

namespace grpc {
class CallbackServerContext;
}

namespace nimbus::server {

/// The `authorization` metadata of a call, if sent.
std::optional<absl::string_view> AuthorizationOf(const grpc::CallbackServerContext& ctx);

/// Admins see everything; others their own.
inline bool CanSee(const Principal& p, const std::string& owner) {
  return p.admin || p.name == owner;
}

/// The job `id` if `p` may see it. Another principal's job is NOT_FOUND
/// with the very message an unknown id gets, so ids cannot be probed.
absl::StatusOr<JobRecord> LoadVisibleJob(JobQueue& store, const Principal& p,
                                         const std::string& id);

/// NOT_FOUND, by field, for an uploaded asset the spec names that `p` does
/// not own (admins may use any).
absl::Status CheckAssetOwnership(const v1::JobSpec& spec, const Principal& p,
                                 const AssetStore& assets);

/// RESOURCE_EXHAUSTED when `p` may not queue another job: too many queued
/// and running jobs, or results over the result quota.
absl::Status CheckJobQuotas(JobHoldings& store, const Principal& p, const Quotas& q);

/// RESOURCE_EXHAUSTED when storing `size` more bytes of `sha256` would take
/// `p` over the asset quota (bytes it already owns cost nothing).
absl::Status CheckAssetQuota(const AssetStore& assets, const Principal& p, const Quotas& q,
                             const std::string& sha256, uint64_t size);

}  // namespace nimbus::server
