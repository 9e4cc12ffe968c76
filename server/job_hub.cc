#include "server/job_hub.h"

#include <algorithm>

namespace nimbus::server {

JobSnapshot JobHub::SnapshotFor(const Entry& e, uint32_t resolution) {
  JobSnapshot s;
  s.version = e.version;
  s.job = e.job;
  if (resolution > 0) {
    auto it = e.previews.find(resolution);
    if (it != e.previews.end()) s.preview = it->second;
  }
  return s;
}

void JobHub::NotifyAll(Entry& e) {
  ++e.version;
  if (!e.job) return;
  for (Subscriber& s : e.subscribers) s.notify(SnapshotFor(e, s.resolution));
}

void JobHub::PublishJob(const v1::Job& job) {
  auto view = std::make_shared<v1::Job>(job);
  view->clear_spec();
  std::lock_guard<std::mutex> lock(mu_);
  Entry& e = jobs_[job.id()];
  e.job = std::move(view);
  NotifyAll(e);
}

void JobHub::PublishPreview(const std::string& job_id, uint32_t resolution, v1::Preview preview) {
  auto p = std::make_shared<const v1::Preview>(std::move(preview));
  std::lock_guard<std::mutex> lock(mu_);
  Entry& e = jobs_[job_id];
  e.previews[resolution] = std::move(p);
  NotifyAll(e);
}

void JobHub::Forget(const std::string& job_id) {
  std::lock_guard<std::mutex> lock(mu_);
  auto it = jobs_.find(job_id);
  if (it != jobs_.end() && it->second.subscribers.empty()) jobs_.erase(it);
}

uint64_t JobHub::Subscribe(const std::string& job_id, uint32_t preview_resolution,
                           double preview_interval, Notify notify) {
  std::lock_guard<std::mutex> lock(mu_);
  Entry& e = jobs_[job_id];
  const uint64_t id = next_subscription_++;
  e.subscribers.push_back({id, preview_resolution, preview_interval, std::move(notify)});
  if (e.job) e.subscribers.back().notify(SnapshotFor(e, preview_resolution));
  return id;
}

void JobHub::Unsubscribe(const std::string& job_id, uint64_t subscription) {
  std::lock_guard<std::mutex> lock(mu_);
  auto it = jobs_.find(job_id);
  if (it == jobs_.end()) return;
  auto& subs = it->second.subscribers;
  subs.erase(std::remove_if(subs.begin(), subs.end(),
                            [&](const Subscriber& s) { return s.id == subscription; }),
             subs.end());
  // A finished job with no watchers has nothing left to fan out.
  if (subs.empty() && (!it->second.job ||
      it->second.job->state() == v1::JOB_STATE_SUCCEEDED ||
       it->second.job->state() == v1::JOB_STATE_FAILED ||
       it->second.job->state() == v1::JOB_STATE_CANCELLED))
    jobs_.erase(it);
}

std::vector<JobHub::PreviewWant> JobHub::WantedPreviews(const std::string& job_id) {
  std::lock_guard<std::mutex> lock(mu_);
  std::vector<PreviewWant> out;
  auto it = jobs_.find(job_id);
  if (it == jobs_.end()) return out;
  for (const Subscriber& s : it->second.subscribers) {
    if (s.resolution == 0) continue;
    auto w = std::find_if(out.begin(), out.end(),
                          [&](const PreviewWant& p) { return p.resolution == s.resolution; });
    if (w == out.end())
      out.push_back({s.resolution, s.interval});
    else
      w->interval_seconds = std::min(w->interval_seconds, s.interval);
  }
  return out;
}

bool JobHub::Watched(const std::string& job_id) {
  std::lock_guard<std::mutex> lock(mu_);
  auto it = jobs_.find(job_id);
  return it != jobs_.end() && !it->second.subscribers.empty();
}

std::shared_ptr<const v1::Job> JobHub::Latest(const std::string& job_id) {
  std::lock_guard<std::mutex> lock(mu_);
  auto it = jobs_.find(job_id);
  return it == jobs_.end() ? nullptr : it->second.job;
}

}  // namespace nimbus::server
