#include "server/timed_job_store.h"

#include <chrono>
#include <iterator>
#include <utility>

namespace nimbus::server {

namespace {

// In StoreCall's order.
constexpr const char* kCallNames[] = {
    "Create",         "Get",
    "List",           "ClaimNext",
    "Heartbeat",      "Complete",
    "AbandonAttempt", "Release",
    "RequestCancel",  "RequeueRunning",
    "SetPriority",    "Usage",
    "SetPinned",      "Delete",
    "ListExpiring",   "MarkResultExpired",
    "SpecsInUse",     "AddPoke",
    "TakePokes",      "ListShards",
    "FindCached",     "WishPreviews",
    "PreviewWishes",  "PutPreview",
    "LatestPreview",  "RegisterWorker",
    "RenewWorker",    "UnregisterWorker",
    "PruneWorkers",   "ListWorkers",
    "AppendEvent",    "ListEvents",
};
static_assert(std::size(kCallNames) == size_t(StoreCall::kCount));

}  // namespace

const char* StoreCallName(StoreCall call) {
  const auto i = size_t(call);
  return i < std::size(kCallNames) ? kCallNames[i] : "unknown";
}

template <typename F>
auto TimedJobStore::Timed(StoreCall call, F&& f) {
  StoreCallObserver* observer = observer_.load(std::memory_order_acquire);
  if (!observer) return f();
  const auto start = std::chrono::steady_clock::now();
  auto result = f();
  observer->ObserveStoreCall(
      call, std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
  return result;
}

absl::StatusOr<JobRecord> TimedJobStore::Create(const NewJob& job, TimeMs now) {
  return Timed(StoreCall::kCreate, [&] { return inner_->Create(job, now); });
}

absl::StatusOr<JobRecord> TimedJobStore::Get(const std::string& id) {
  return Timed(StoreCall::kGet, [&] { return inner_->Get(id); });
}

absl::StatusOr<ListPage> TimedJobStore::List(const ListOptions& options) {
  return Timed(StoreCall::kList, [&] { return inner_->List(options); });
}

absl::StatusOr<std::optional<JobRecord>> TimedJobStore::ClaimNext(
    const std::string& worker_id, TimeMs now, TimeMs lease_ms, uint32_t max_attempts,
    std::vector<JobRecord>* given_up) {
  return Timed(StoreCall::kClaimNext,
               [&] { return inner_->ClaimNext(worker_id, now, lease_ms, max_attempts, given_up); });
}

absl::StatusOr<bool> TimedJobStore::Heartbeat(const std::string& id, const std::string& worker_id,
                                              TimeMs now, TimeMs lease_ms, uint64_t progress_done,
                                              uint64_t progress_total) {
  return Timed(StoreCall::kHeartbeat, [&] {
    return inner_->Heartbeat(id, worker_id, now, lease_ms, progress_done, progress_total);
  });
}

absl::Status TimedJobStore::Complete(const std::string& id, const std::string& worker_id,
                                     const Completion& completion, TimeMs now) {
  return Timed(StoreCall::kComplete,
               [&] { return inner_->Complete(id, worker_id, completion, now); });
}

absl::Status TimedJobStore::AbandonAttempt(const std::string& id, const std::string& worker_id,
                                           const std::string& error, int error_code) {
  return Timed(StoreCall::kAbandonAttempt,
               [&] { return inner_->AbandonAttempt(id, worker_id, error, error_code); });
}

absl::Status TimedJobStore::Release(const std::string& id, const std::string& worker_id) {
  return Timed(StoreCall::kRelease, [&] { return inner_->Release(id, worker_id); });
}

absl::StatusOr<JobRecord> TimedJobStore::RequestCancel(const std::string& id, TimeMs now,
                                                       const std::string& by) {
  return Timed(StoreCall::kRequestCancel, [&] { return inner_->RequestCancel(id, now, by); });
}

absl::StatusOr<int> TimedJobStore::RequeueRunning() {
  return Timed(StoreCall::kRequeueRunning, [&] { return inner_->RequeueRunning(); });
}

absl::StatusOr<JobRecord> TimedJobStore::SetPriority(const std::string& id, int priority) {
  return Timed(StoreCall::kSetPriority, [&] { return inner_->SetPriority(id, priority); });
}

void TimedJobStore::SetChangeListener(JobChangeListener listener) {
  inner_->SetChangeListener(std::move(listener));
}

absl::StatusOr<OwnerUsage> TimedJobStore::Usage(const std::string& owner) {
  return Timed(StoreCall::kUsage, [&] { return inner_->Usage(owner); });
}

absl::StatusOr<JobRecord> TimedJobStore::SetPinned(const std::string& id, bool pinned) {
  return Timed(StoreCall::kSetPinned, [&] { return inner_->SetPinned(id, pinned); });
}

absl::Status TimedJobStore::Delete(const std::string& id) {
  return Timed(StoreCall::kDelete, [&] { return inner_->Delete(id); });
}

absl::StatusOr<std::vector<JobRecord>> TimedJobStore::ListExpiring(TimeMs cutoff, int limit) {
  return Timed(StoreCall::kListExpiring, [&] { return inner_->ListExpiring(cutoff, limit); });
}

absl::Status TimedJobStore::MarkResultExpired(const std::string& id, TimeMs now) {
  return Timed(StoreCall::kMarkResultExpired, [&] { return inner_->MarkResultExpired(id, now); });
}

absl::StatusOr<std::vector<std::string>> TimedJobStore::SpecsInUse() {
  return Timed(StoreCall::kSpecsInUse, [&] { return inner_->SpecsInUse(); });
}

absl::StatusOr<PokeRecord> TimedJobStore::AddPoke(const std::string& id, const PokeRecord& poke) {
  return Timed(StoreCall::kAddPoke, [&] { return inner_->AddPoke(id, poke); });
}

absl::StatusOr<std::vector<PokeRecord>> TimedJobStore::TakePokes(const std::string& id,
                                                                 const std::string& worker_id,
                                                                 int64_t frame) {
  return Timed(StoreCall::kTakePokes, [&] { return inner_->TakePokes(id, worker_id, frame); });
}

absl::StatusOr<std::vector<JobRecord>> TimedJobStore::ListShards(const std::string& parent_id) {
  return Timed(StoreCall::kListShards, [&] { return inner_->ListShards(parent_id); });
}

absl::StatusOr<std::optional<JobRecord>> TimedJobStore::FindCached(const std::string& spec_sha256,
                                                                   const std::string& owner) {
  return Timed(StoreCall::kFindCached, [&] { return inner_->FindCached(spec_sha256, owner); });
}

absl::Status TimedJobStore::WishPreviews(const std::string& id,
                                         const std::vector<PreviewWish>& wishes, TimeMs until) {
  return Timed(StoreCall::kWishPreviews, [&] { return inner_->WishPreviews(id, wishes, until); });
}

absl::StatusOr<std::vector<PreviewWish>> TimedJobStore::PreviewWishes(const std::string& id,
                                                                      TimeMs now) {
  return Timed(StoreCall::kPreviewWishes, [&] { return inner_->PreviewWishes(id, now); });
}

absl::Status TimedJobStore::PutPreview(const std::string& id, uint32_t resolution,
                                       uint64_t sequence, const std::string& preview) {
  return Timed(StoreCall::kPutPreview,
               [&] { return inner_->PutPreview(id, resolution, sequence, preview); });
}

absl::StatusOr<std::string> TimedJobStore::LatestPreview(const std::string& id,
                                                         uint32_t resolution) {
  return Timed(StoreCall::kLatestPreview, [&] { return inner_->LatestPreview(id, resolution); });
}

absl::Status TimedJobStore::RegisterWorker(const WorkerInfo& info) {
  return Timed(StoreCall::kRegisterWorker, [&] { return inner_->RegisterWorker(info); });
}

absl::Status TimedJobStore::RenewWorker(const std::string& replica_id, uint32_t jobs_running,
                                        int64_t now) {
  return Timed(StoreCall::kRenewWorker,
               [&] { return inner_->RenewWorker(replica_id, jobs_running, now); });
}

absl::Status TimedJobStore::UnregisterWorker(const std::string& replica_id) {
  return Timed(StoreCall::kUnregisterWorker, [&] { return inner_->UnregisterWorker(replica_id); });
}

absl::StatusOr<int> TimedJobStore::PruneWorkers(int64_t cutoff) {
  return Timed(StoreCall::kPruneWorkers, [&] { return inner_->PruneWorkers(cutoff); });
}

absl::StatusOr<std::vector<WorkerInfo>> TimedJobStore::ListWorkers() {
  return Timed(StoreCall::kListWorkers, [&] { return inner_->ListWorkers(); });
}

absl::Status TimedJobStore::AppendEvent(const std::string& job_id, const JobEvent& event) {
  return Timed(StoreCall::kAppendEvent, [&] { return inner_->AppendEvent(job_id, event); });
}

absl::StatusOr<JobEventPage> TimedJobStore::ListEvents(const std::string& job_id, int64_t after,
                                                       int limit) {
  return Timed(StoreCall::kListEvents, [&] { return inner_->ListEvents(job_id, after, limit); });
}

}  // namespace nimbus::server
