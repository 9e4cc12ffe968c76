#include "server/access.h"

#include <grpcpp/grpcpp.h>

#include "absl/strings/str_cat.h"
#include "proto/asset_paths.h"
#include "server/bounded_text.h"

namespace nimbus::server {

std::optional<absl::string_view> AuthorizationOf(const grpc::CallbackServerContext& ctx) {
  const auto& md = ctx.client_metadata();
  auto it = md.find("authorization");
  if (it == md.end()) return std::nullopt;
  return absl::string_view(it->second.data(), it->second.size());
}

absl::StatusOr<JobRecord> LoadVisibleJob(JobQueue& store, const Principal& p,
                                         const std::string& id) {
  auto rec = store.Get(id);
  if (!rec.ok()) return rec.status();
  if (!CanSee(p, rec->owner))
    return absl::NotFoundError(absl::StrCat("job \"", EchoId(id), "\" not found"));
  return rec;
}

absl::Status CheckAssetOwnership(const v1::JobSpec& spec, const Principal& p,
                                 const AssetStore& assets) {
  if (p.admin) return absl::OkStatus();
  v1::JobSpec copy = spec;  // ForEachAsset visits mutable assets
  absl::Status result;
  spec::ForEachAsset(copy, [&](const std::string& field, v1::Asset& asset) {
    if (!result.ok() || asset.source_case() != v1::Asset::kSha256) return;
    if (assets.IsOwner(asset.sha256(), p.name)) return;
    // The same words whether the bytes exist or belong to someone else.
    result = absl::NotFoundError(absl::StrCat(field, ".sha256: no uploaded asset ",
                                              EchoId(asset.sha256()), " (upload it first)"));
  });
  return result;
}

absl::Status CheckJobQuotas(JobHoldings& store, const Principal& p, const Quotas& q) {
  if (q.jobs == 0 && q.result_bytes == 0) return absl::OkStatus();
  auto usage = store.Usage(p.name);
  if (!usage.ok()) return usage.status();
  if (q.jobs > 0 && usage->active_jobs >= q.jobs)
    return absl::ResourceExhaustedError(absl::StrCat(
        "job quota: principal ", p.name, " has ", usage->active_jobs,
        " queued or running jobs, the quota is ", q.jobs, "; wait for one to end or cancel one"));
  if (q.result_bytes > 0 && usage->result_bytes >= q.result_bytes)
    return absl::ResourceExhaustedError(
        absl::StrCat("result quota: principal ", p.name, " keeps ", usage->result_bytes,
                     " bytes of results, the quota is ", q.result_bytes,
                     " bytes; delete jobs (nimbus delete) or wait for results to expire"));
  return absl::OkStatus();
}

absl::Status CheckAssetQuota(const AssetStore& assets, const Principal& p, const Quotas& q,
                             const std::string& sha256, uint64_t size) {
  if (q.asset_bytes == 0 || assets.IsOwner(sha256, p.name)) return absl::OkStatus();
  const uint64_t used = assets.OwnedBytes(p.name);
  if (used + size <= q.asset_bytes) return absl::OkStatus();
  return absl::ResourceExhaustedError(absl::StrCat(
      "asset quota: principal ", p.name, " stores ", used, " bytes of assets; this upload of ",
      size, " bytes would pass the quota of ", q.asset_bytes, " bytes"));
}

}  // namespace nimbus::server
