// A job store that times its calls: it forwards every call of every
// interface of JobStore to the store it wraps and reports how long each
// took (nimbus_store_call_duration_seconds, docs/operator_guide.md
// "Metrics"), so the service, the workers, the sweeper and the metrics are
// measured where they meet the store, whichever store it is.
#pragma once

#include <atomic>
#include <memory>
#include <string>
#include <vector>

#include "server/job_store.h"

namespace nimbus::server {

/// The store calls timed: the methods of JobStore's interfaces by name
/// (StoreCallName), SetChangeListener excepted.
enum class StoreCall {
  kCreate,
  kGet,
  kList,
  kClaimNext,
  kHeartbeat,
  kComplete,
  kAbandonAttempt,
  kRelease,
  kRequestCancel,
  kRequeueRunning,
  kSetPriority,
  kUsage,
  kSetPinned,
  kDelete,
  kListExpiring,
  kMarkResultExpired,
  kSpecsInUse,
  kAddPoke,
  kTakePokes,
  kListShards,
  kFindCached,
  kWishPreviews,
  kPreviewWishes,
  kPutPreview,
  kLatestPreview,
  kRegisterWorker,
  kRenewWorker,
  kUnregisterWorker,
  kPruneWorkers,
  kListWorkers,
  kAppendEvent,
  kListEvents,
  kCount  // not a call
};

/// The method's name: "ClaimNext", "Heartbeat", ...
const char* StoreCallName(StoreCall call);

/// @brief Told the duration of each store call, on the calling thread;
/// must be cheap and thread-safe.
class StoreCallObserver {
 public:
  virtual ~StoreCallObserver() = default;
  virtual void ObserveStoreCall(StoreCall call, double seconds) = 0;
};

/// @brief Wraps a JobStore; each call goes to it unchanged (same results,
/// same errors, same feed) and its duration to the observer, when one is
/// set. The observer must outlive the calls made while it is set.
class TimedJobStore final : public JobStore {
 public:
  explicit TimedJobStore(std::unique_ptr<JobStore> inner) : inner_(std::move(inner)) {}
  void set_observer(StoreCallObserver* observer) { observer_.store(observer); }

  // JobQueue
  absl::StatusOr<JobRecord> Create(const NewJob& job, TimeMs now) override;
  absl::StatusOr<JobRecord> Get(const std::string& id) override;
  absl::StatusOr<ListPage> List(const ListOptions& options) override;
  absl::StatusOr<std::optional<JobRecord>> ClaimNext(const std::string& worker_id, TimeMs now,
                                                     TimeMs lease_ms, uint32_t max_attempts,
                                                     std::vector<JobRecord>* given_up) override;
  absl::StatusOr<bool> Heartbeat(const std::string& id, const std::string& worker_id, TimeMs now,
                                 TimeMs lease_ms, uint64_t progress_done,
                                 uint64_t progress_total) override;
  absl::Status Complete(const std::string& id, const std::string& worker_id,
                        const Completion& completion, TimeMs now) override;
  absl::Status AbandonAttempt(const std::string& id, const std::string& worker_id,
                              const std::string& error, int error_code) override;
  absl::Status Release(const std::string& id, const std::string& worker_id) override;
  absl::StatusOr<JobRecord> RequestCancel(const std::string& id, TimeMs now,
                                          const std::string& by) override;
  absl::StatusOr<int> RequeueRunning() override;
  absl::StatusOr<JobRecord> SetPriority(const std::string& id, int priority) override;
  void SetChangeListener(JobChangeListener listener) override;
  // JobHoldings
  absl::StatusOr<OwnerUsage> Usage(const std::string& owner) override;
  absl::StatusOr<JobRecord> SetPinned(const std::string& id, bool pinned) override;
  absl::Status Delete(const std::string& id) override;
  absl::StatusOr<std::vector<JobRecord>> ListExpiring(TimeMs cutoff, int limit) override;
  absl::Status MarkResultExpired(const std::string& id, TimeMs now) override;
  absl::StatusOr<std::vector<std::string>> SpecsInUse() override;
  // PokeStore, ShardStore, ResultCacheIndex
  absl::StatusOr<PokeRecord> AddPoke(const std::string& id, const PokeRecord& poke) override;
  absl::StatusOr<std::vector<PokeRecord>> TakePokes(const std::string& id,
                                                    const std::string& worker_id,
                                                    int64_t frame) override;
  absl::StatusOr<std::vector<JobRecord>> ListShards(const std::string& parent_id) override;
  absl::StatusOr<std::optional<JobRecord>> FindCached(const std::string& spec_sha256,
                                                      const std::string& owner) override;
  // PreviewStore
  absl::Status WishPreviews(const std::string& id, const std::vector<PreviewWish>& wishes,
                            TimeMs until) override;
  absl::StatusOr<std::vector<PreviewWish>> PreviewWishes(const std::string& id,
                                                         TimeMs now) override;
  absl::Status PutPreview(const std::string& id, uint32_t resolution, uint64_t sequence,
                          const std::string& preview) override;
  absl::StatusOr<std::string> LatestPreview(const std::string& id, uint32_t resolution) override;
  // WorkerRegistry
  absl::Status RegisterWorker(const WorkerInfo& info) override;
  absl::Status RenewWorker(const std::string& replica_id, uint32_t jobs_running,
                           int64_t now) override;
  absl::Status UnregisterWorker(const std::string& replica_id) override;
  absl::StatusOr<int> PruneWorkers(int64_t cutoff) override;
  absl::StatusOr<std::vector<WorkerInfo>> ListWorkers() override;
  // JobEventLog
  absl::Status AppendEvent(const std::string& job_id, const JobEvent& event) override;
  absl::StatusOr<JobEventPage> ListEvents(const std::string& job_id, int64_t after,
                                          int limit) override;

 private:
  template <typename F>
  auto Timed(StoreCall call, F&& f);

  std::unique_ptr<JobStore> inner_;
  std::atomic<StoreCallObserver*> observer_{nullptr};
};

}  // namespace nimbus::server
