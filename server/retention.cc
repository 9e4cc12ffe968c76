#include "server/retention.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <set>

#include "absl/strings/str_cat.h"
#include "nimbus/v1/spec.pb.h"
#include "proto/asset_paths.h"
#include "server/job_view.h"

namespace nimbus::server {

namespace {

// Expired results per store query; the loop continues until none are left.
constexpr int kBatch = 100;

// The hashes of every asset the given specs name.
std::set<std::string> AssetsOf(const std::vector<std::string>& specs) {
  std::set<std::string> hashes;
  for (const std::string& bytes : specs) {
    v1::JobSpec spec;
    if (!spec.ParseFromString(bytes)) continue;
    spec::ForEachAsset(spec, [&](const std::string&, v1::Asset& asset) {
      if (asset.source_case() == v1::Asset::kSha256) hashes.insert(asset.sha256());
    });
  }
  return hashes;
}

}  // namespace

int64_t SweepIntervalMs(int64_t retention_ms) {
  return std::clamp<int64_t>(retention_ms / 10, 100, 60'000);
}

void RetentionSweeper::Start() {
  if (retention_ms_ <= 0 || thread_.joinable()) return;
  thread_ = std::thread([this] {
    std::unique_lock<std::mutex> lock(mu_);
    while (!stop_) {
      lock.unlock();
      SweepOnce(NowMs());
      lock.lock();
      cv_.wait_for(lock, std::chrono::milliseconds(interval_ms_), [this] { return stop_; });
    }
  });
}

void RetentionSweeper::Stop() {
  {
    std::lock_guard<std::mutex> lock(mu_);
    stop_ = true;
  }
  cv_.notify_all();
  if (thread_.joinable()) thread_.join();
}

SweepCounts RetentionSweeper::SweepOnce(TimeMs now) {
  SweepCounts counts;
  const TimeMs cutoff = now - retention_ms_;
  while (true) {
    auto expiring = store_->ListExpiring(cutoff, kBatch);
    if (!expiring.ok()) {
      spdlog::error("event=retention_failed error=\"{}\"", expiring.status().ToString());
      return counts;
    }
    for (const JobRecord& job : *expiring) {
      auto freed = results_->Delete(job.result_key);
      absl::Status st = freed.ok() ? store_->MarkResultExpired(job.id, now) : freed.status();
      if (!st.ok()) {
        spdlog::error("job={} event=retention_failed error=\"{}\"", job.id, st.ToString());
        return counts;
      }
      spdlog::info("job={} event=result_expired freed_bytes={}", job.id, *freed);
      if (events_ != nullptr)
        LogJobEvent(*events_, job.id, "result_expired", {{"freed_bytes", absl::StrCat(*freed)}});
      ++counts.results;
    }
    if (expiring->size() < size_t(kBatch)) break;
  }
  if (assets_ != nullptr) {
    auto specs = store_->SpecsInUse();
    if (!specs.ok()) {
      spdlog::error("event=retention_failed error=\"{}\"", specs.status().ToString());
      return counts;
    }
    const std::chrono::sys_time<std::chrono::milliseconds> sys_cutoff{
        std::chrono::milliseconds(cutoff)};
    const auto file_cutoff = std::chrono::file_clock::from_sys(sys_cutoff);
    counts.assets = assets_->ExpireUnreferenced(file_cutoff, AssetsOf(*specs));
    if (counts.assets > 0) spdlog::info("event=assets_expired count={}", counts.assets);
  }
  return counts;
}

}  // namespace nimbus::server
