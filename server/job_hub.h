// In-memory fan-out of live job state to watchers. Each job keeps only its
// newest state and newest preview per resolution, so a slow watcher skips
// to the latest instead of queueing: memory per job is bounded.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "nimbus/v1/nimbus_service.pb.h"

namespace nimbus::server {

/// What a watcher sees: the newest job view and, for its resolution, the
/// newest preview. Immutable once published; shared by pointer.
struct JobSnapshot {
  uint64_t version = 0;
  std::shared_ptr<const v1::Job> job;
  std::shared_ptr<const v1::Preview> preview;  // may be null
};

/// @brief Publishes job updates (worker side) to subscribed watchers
/// (gRPC side). Notifications are called under the hub's lock and must only
/// copy the snapshot and kick off a write; they must not call back into the hub.
class JobHub {
 public:
  using Notify = std::function<void(const JobSnapshot&)>;

  struct PreviewWant {
    uint32_t resolution;
    double interval_seconds;
  };

  /// Replaces the job view (spec stripped) and notifies watchers.
  void PublishJob(const v1::Job& job);
  /// Stores the newest preview for its resolution and notifies watchers of it.
  void PublishPreview(const std::string& job_id, uint32_t resolution, v1::Preview preview);
  /// Drops a finished job's previews once it has no watchers.
  void Forget(const std::string& job_id);

  /// Returns a subscription id; `notify` runs at once with the current
  /// snapshot if the hub knows the job.
  uint64_t Subscribe(const std::string& job_id, uint32_t preview_resolution,
                     double preview_interval, Notify notify);
  void Unsubscribe(const std::string& job_id, uint64_t subscription);

  /// The preview resolutions watchers of `job_id` want, with the shortest
  /// interval asked for each.
  std::vector<PreviewWant> WantedPreviews(const std::string& job_id);
  /// Whether anyone watches `job_id` here.
  bool Watched(const std::string& job_id);
  /// The newest job view, or null.
  std::shared_ptr<const v1::Job> Latest(const std::string& job_id);

 private:
  struct Subscriber {
    uint64_t id;
    uint32_t resolution;
    double interval;
    Notify notify;
  };
  struct Entry {
    uint64_t version = 0;
    std::shared_ptr<const v1::Job> job;
    std::map<uint32_t, std::shared_ptr<const v1::Preview>> previews;
    std::vector<Subscriber> subscribers;
  };
  void NotifyAll(Entry& e);
  static JobSnapshot SnapshotFor(const Entry& e, uint32_t resolution);

  std::mutex mu_;
  std::map<std::string, Entry> jobs_;
  uint64_t next_subscription_ = 1;
};

}  // namespace nimbus::server
