// The job store interfaces: durable job records with claims and leases (the
// queue) and the extensions some job kinds need beside it, so a shared
// PostgreSQL backend with several replicas can replace the embedded SQLite
// one without touching the service or the workers.
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/str_cat.h"
#include "server/job_event_log.h"
#include "server/worker_registry.h"

namespace nimbus::server {

enum class JobState { kQueued = 1, kRunning = 2, kSucceeded = 3, kFailed = 4, kCancelled = 5 };

inline bool IsTerminal(JobState s) {
  return s == JobState::kSucceeded || s == JobState::kFailed || s == JobState::kCancelled;
}

/// The range and default of job priorities (higher is claimed first).
inline constexpr int kMinPriority = 0;
inline constexpr int kMaxPriority = 100;
inline constexpr int kDefaultPriority = 50;

/// Milliseconds since the Unix epoch.
using TimeMs = int64_t;

struct JobRecord {
  std::string id;
  std::string name;
  JobState state = JobState::kQueued;
  /// Serialised nimbus.v1.JobSpec (binary protobuf); the store never parses it.
  std::string spec;
  /// Client idempotency key; empty when none.
  std::string request_id;
  TimeMs create_time = 0;
  TimeMs start_time = 0;  // last claim
  TimeMs end_time = 0;
  uint32_t attempts = 0;
  bool cancel_requested = false;
  /// Holder of the current claim and when it lapses (RUNNING jobs only).
  std::string worker_id;
  TimeMs lease_expiry = 0;
  uint64_t progress_done = 0;
  uint64_t progress_total = 0;
  std::string error;
  /// absl::StatusCode of a FAILED or CANCELLED job; 0 otherwise.
  int error_code = 0;
  /// Set when SUCCEEDED.
  std::string result_key;
  uint64_t result_size = 0;
  std::string result_sha256;
  /// Newline-separated warnings.
  std::string warnings;
  uint64_t estimated_memory_bytes = 0;
  /// The principal the job (and its result) belongs to; empty for jobs
  /// stored before owners were kept (only admins see those).
  std::string owner;
  /// Pinned results never expire.
  bool pinned = false;
  /// When the retention sweep deleted the result files (0: not expired).
  TimeMs result_expire_time = 0;
  // Sharded jobs and the result cache (docs/sharding.md, docs/result_cache.md).
  /// Set on a shard: the job it belongs to.
  std::string parent_id;
  uint32_t shard_index = 0;
  /// On a parent and on each of its shards; 0 for an ordinary job.
  uint32_t shard_count = 0;
  /// On a parent: shards not yet SUCCEEDED. The parent is not claimable
  /// (its merge cannot run) while this is > 0.
  uint32_t shards_pending = 0;
  std::string spec_sha256;
  /// A result-cache hit: the job whose result this one copies.
  std::string cached_from;
  /// Claim order (docs/operator_guide.md "Claim order"): kMinPriority to
  /// kMaxPriority, higher first. Shards carry their parent's.
  int priority = kDefaultPriority;
  /// Set by RetryJob: the FAILED or CANCELLED job this one repeats.
  std::string retried_from;
};

/// What a principal holds, for quotas.
struct OwnerUsage {
  /// QUEUED and RUNNING jobs.
  uint64_t active_jobs = 0;
  /// Bytes of unexpired results of SUCCEEDED jobs.
  uint64_t result_bytes = 0;
};

struct Completion {
  JobState state = JobState::kSucceeded;  // a terminal state
  std::string error;
  /// absl::StatusCode of the failure (CANCELLED for a cancelled job).
  int error_code = 0;
  std::string result_key;
  uint64_t result_size = 0;
  std::string result_sha256;
  std::string warnings;
};

struct NewJob {
  std::string id;
  std::string name;
  std::string spec;
  std::string request_id;
  uint64_t progress_total = 0;
  std::string warnings;
  uint64_t estimated_memory_bytes = 0;
  std::string owner;
  /// > 1: a sharded job (docs/sharding.md). Create inserts the parent and its
  /// shards in one transaction.
  uint32_t shard_count = 0;
  /// sha256 (hex) of the canonical spec, for the result cache; may be empty.
  std::string spec_sha256;
  /// A result-cache hit (docs/result_cache.md): Create inserts the job
  /// SUCCEEDED at once, with `cached_result`'s result fields, and records
  /// `cached_from` (the job whose result it copies).
  std::string cached_from;
  Completion cached_result;
  /// kMinPriority..kMaxPriority (Create refuses others); shards inherit it.
  int priority = kDefaultPriority;
  /// A retry of this FAILED or CANCELLED job (RetryJob).
  std::string retried_from;
  /// The principal submitting it. When set, Create logs the job's
  /// `submitted` event (SubmittedEvent) in its transaction, so the event
  /// comes before any claim's; an idempotent repeat logs none.
  std::string submitted_by;
};

struct ListOptions {
  int page_size = 50;
  /// Opaque token from a previous page; empty for the first page.
  std::string page_token;
  std::optional<JobState> state;
  /// Only this principal's jobs, when set.
  std::optional<std::string> owner;
  /// A page ends before its jobs' text (names, errors, warnings, ids) would
  /// pass this many bytes, so a response stays far below gRPC's message
  /// limit; a page always holds at least one job.
  uint64_t max_bytes = uint64_t{1} << 20;
  /// Shards are hidden from listings unless asked for.
  bool include_shards = false;
};

struct ListPage {
  /// Newest first.
  std::vector<JobRecord> jobs;
  std::string next_page_token;
};

/// @brief A poke on a running jelly job: an impulse or a drag on one body,
/// durable so that a restarted attempt replays it at the same frame.
struct PokeRecord {
  /// Arrival order in the store (set by AddPoke).
  int64_t seq = 0;
  /// The frame it acts at, given by the job's runner when it takes the
  /// poke (the first frame it has not simulated); -1 until then.
  int64_t frame = -1;
  int32_t body = 0;
  bool drag = false;
  /// Impulse, or drag target.
  double x = 0, y = 0, z = 0;
  double drag_stiffness = 0;
  uint32_t drag_frames = 0;
};

/// @brief A change to a job on a shared store's feed, made by any replica.
struct JobChange {
  /// Empty: changes may have been missed (the feed reconnected).
  std::string job_id;
  /// The job may be claimable now (submitted, or given back): wake a worker.
  bool claimable = false;
  /// A new preview of the job was stored (PutPreview).
  bool preview = false;
};

/// A preview resolution watchers on some replica want, and how often.
struct PreviewWish {
  uint32_t resolution = 0;
  double interval_seconds = 1.0;
};
using JobChangeListener = std::function<void(const JobChange&)>;

// A store implements the queue (JobQueue) and, beside it, one small
// interface per extension: what results and quotas hold (JobHoldings),
// jelly pokes (PokeStore), shards (ShardStore), the result cache
// (ResultCacheIndex), previews across replicas (PreviewStore), the worker
// registry (WorkerRegistry) and the job event log (JobEventLog). Code that
// needs one extension takes that interface alone. All methods are
// thread-safe.

/// @brief The queue: create, get, list, claim, lease, complete, cancel, and
/// the feed of changes to it.
class JobQueue {
 public:
  virtual ~JobQueue() = default;

  /// Inserts a QUEUED job. A name longer than kMaxJobNameBytes is
  /// INVALID_ARGUMENT; warnings are bounded (server/bounded_text.h). When
  /// `job.request_id` is non-empty and a job with that key exists, returns
  /// the existing job instead (idempotent submit).
  virtual absl::StatusOr<JobRecord> Create(const NewJob& job, TimeMs now) = 0;
  /// NOT_FOUND for an unknown id.
  virtual absl::StatusOr<JobRecord> Get(const std::string& id) = 0;
  virtual absl::StatusOr<ListPage> List(const ListOptions& options) = 0;

  /// Atomically claims the next job by the claim order (a RUNNING job
  /// whose lease has lapsed, or a QUEUED job: the highest priority, then
  /// fair share between owners, then the owner's oldest job; the rule is
  /// in docs/operator_guide.md "Claim order"): it becomes RUNNING, held
  /// by `worker_id` until now + lease, attempts + 1. nullopt when nothing
  /// is claimable. With `max_attempts` > 0, a job that has already had that
  /// many attempts is not claimed but FAILED, with the error of its last
  /// attempt (AbandonAttempt) or a note that its worker stopped without
  /// one: a job that kills its worker or cannot record its end does not
  /// loop forever. Such jobs are appended to `given_up` (when not null) as
  /// they are afterwards.
  virtual absl::StatusOr<std::optional<JobRecord>> ClaimNext(
      const std::string& worker_id, TimeMs now, TimeMs lease_ms, uint32_t max_attempts = 0,
      std::vector<JobRecord>* given_up = nullptr) = 0;
  /// Extends the lease and records progress. FAILED_PRECONDITION when the
  /// worker no longer holds the claim. Returns whether cancel was requested.
  virtual absl::StatusOr<bool> Heartbeat(const std::string& id, const std::string& worker_id,
                                         TimeMs now, TimeMs lease_ms, uint64_t progress_done,
                                         uint64_t progress_total) = 0;
  /// Moves a claimed job to a terminal state. FAILED_PRECONDITION when the
  /// worker no longer holds the claim. The error and warnings are stored
  /// bounded (BoundText), however long they arrive.
  virtual absl::Status Complete(const std::string& id, const std::string& worker_id,
                                const Completion& completion, TimeMs now) = 0;
  /// Ends an attempt that could not be completed: records its error (kept
  /// for the job's final message once attempts run out) and gives the job
  /// back to the queue. FAILED_PRECONDITION when the worker no longer
  /// holds the claim.
  virtual absl::Status AbandonAttempt(const std::string& id, const std::string& worker_id,
                                      const std::string& error, int error_code) = 0;
  /// Gives a claimed job back to the queue (graceful shutdown).
  virtual absl::Status Release(const std::string& id, const std::string& worker_id) = 0;
  /// QUEUED jobs become CANCELLED at once, logged `cancelled` (field `by`)
  /// in the same transaction, so only the call that ended the job logs its
  /// end; RUNNING ones get cancel_requested (their worker finishes the
  /// transition and logs it); terminal jobs are unchanged. Returns the job
  /// as it is afterwards. NOT_FOUND for an unknown id.
  virtual absl::StatusOr<JobRecord> RequestCancel(const std::string& id, TimeMs now,
                                                  const std::string& by) = 0;
  /// Single-node recovery after a crash: every RUNNING job becomes QUEUED
  /// again (its lease holder is gone). Returns how many were requeued.
  virtual absl::StatusOr<int> RequeueRunning() = 0;

  /// Changes a QUEUED job's priority (and its queued shards'); returns the
  /// job. INVALID_ARGUMENT naming `priority` outside kMinPriority..
  /// kMaxPriority, NOT_FOUND for an unknown id, FAILED_PRECONDITION for a
  /// job that is not QUEUED.
  virtual absl::StatusOr<JobRecord> SetPriority(const std::string& id, int priority) {
    (void)priority;
    return absl::UnimplementedError(absl::StrCat("this store cannot reprioritise job ", id));
  }
  /// Cross-replica change feed: `listener` runs, on a thread of the
  /// store's, after every committed change to any job by any process
  /// sharing the store, including this one. Null stops the feed (call it
  /// before whatever the listener uses goes away). A store only one process
  /// uses has no feed: by default this does nothing.
  virtual void SetChangeListener(JobChangeListener listener) { (void)listener; }
};

/// @brief What jobs and their results hold: quotas, pins, deletion and
/// the retention sweep.
class JobHoldings {
 public:
  virtual ~JobHoldings() = default;

  /// Quota accounting for one principal.
  virtual absl::StatusOr<OwnerUsage> Usage(const std::string& owner) = 0;
  /// Pins or unpins a job's result; returns the job. NOT_FOUND for an
  /// unknown id.
  virtual absl::StatusOr<JobRecord> SetPinned(const std::string& id, bool pinned) = 0;
  /// Removes a finished job's record. FAILED_PRECONDITION for a job that
  /// is still QUEUED or RUNNING, NOT_FOUND for an unknown id.
  virtual absl::Status Delete(const std::string& id) = 0;
  /// Up to `limit` SUCCEEDED, unpinned jobs that ended before `cutoff` and
  /// whose result has not expired yet, oldest first.
  virtual absl::StatusOr<std::vector<JobRecord>> ListExpiring(TimeMs cutoff, int limit) = 0;
  /// Records that the result files of `id` were deleted at `now`.
  virtual absl::Status MarkResultExpired(const std::string& id, TimeMs now) = 0;
  /// Serialised specs of the jobs whose assets must be kept: QUEUED,
  /// RUNNING and pinned ones.
  virtual absl::StatusOr<std::vector<std::string>> SpecsInUse() = 0;
};

/// @brief Pokes on running jelly jobs (docs/jelly.md).
class PokeStore {
 public:
  virtual ~PokeStore() = default;

  /// Records a poke for a RUNNING job, without a frame yet; returns it
  /// with its seq. NOT_FOUND for an unknown id, FAILED_PRECONDITION when
  /// the job is not running.
  virtual absl::StatusOr<PokeRecord> AddPoke(const std::string& id, const PokeRecord& poke) = 0;
  /// For the worker holding the claim: gives every poke of `id` without a
  /// frame the frame `frame`, then returns the pokes at `frame` in arrival
  /// order. FAILED_PRECONDITION when the worker no longer holds the claim.
  virtual absl::StatusOr<std::vector<PokeRecord>> TakePokes(const std::string& id,
                                                            const std::string& worker_id,
                                                            int64_t frame) = 0;
};

/// @brief The shards of sharded jobs (docs/sharding.md); the queue creates,
/// claims and completes them as jobs.
class ShardStore {
 public:
  virtual ~ShardStore() = default;

  /// The shards of `parent_id` in shard order (NOT_FOUND for an unknown id).
  virtual absl::StatusOr<std::vector<JobRecord>> ListShards(const std::string& parent_id) = 0;
};

/// @brief Finished jobs by spec hash (docs/result_cache.md).
class ResultCacheIndex {
 public:
  virtual ~ResultCacheIndex() = default;

  /// The newest SUCCEEDED, unexpired, top-level job of `owner` with this
  /// spec hash, or nullopt (result cache).
  virtual absl::StatusOr<std::optional<JobRecord>> FindCached(const std::string& spec_sha256,
                                                              const std::string& owner) = 0;
};

/// @brief Previews across replicas. A watcher's replica records what it wants
/// (WishPreviews); the replica running the job reads the wishes at each
/// heartbeat, makes those previews and stores the newest one per
/// resolution (PutPreview, announced on the feed); watchers' replicas read
/// it (LatestPreview). In a store only one process uses, the job hub
/// carries previews in memory and these do nothing (the defaults).
class PreviewStore {
 public:
  virtual ~PreviewStore() = default;

  /// Wishes for `id`'s previews, valid until `until` unless renewed.
  virtual absl::Status WishPreviews(const std::string& id, const std::vector<PreviewWish>& wishes,
                                    TimeMs until) {
    (void)id, (void)wishes, (void)until;
    return absl::OkStatus();
  }
  /// Unexpired wishes for `id`'s previews, one per resolution.
  virtual absl::StatusOr<std::vector<PreviewWish>> PreviewWishes(const std::string& id,
                                                                 TimeMs now) {
    (void)id, (void)now;
    return std::vector<PreviewWish>();
  }
  /// Stores the newest preview (a serialised nimbus.v1.Preview) of `id` at
  /// `resolution`; an older `sequence` than the stored one is ignored.
  virtual absl::Status PutPreview(const std::string& id, uint32_t resolution, uint64_t sequence,
                                  const std::string& preview) {
    (void)id, (void)resolution, (void)sequence, (void)preview;
    return absl::OkStatus();
  }
  /// The newest stored preview of `id` at `resolution`; NOT_FOUND if none.
  virtual absl::StatusOr<std::string> LatestPreview(const std::string& id, uint32_t resolution) {
    (void)resolution;
    return absl::NotFoundError(absl::StrCat("no stored preview of job ", id));
  }
};

/// @brief A whole job store: the queue and every extension.
class JobStore : public JobQueue,
                 public JobHoldings,
                 public PokeStore,
                 public ShardStore,
                 public ResultCacheIndex,
                 public PreviewStore,
                 public WorkerRegistry,
                 public JobEventLog {};

/// Id of shard `index` of `parent_id`: "<parent id>.shard-<index>".
inline std::string ShardJobId(const std::string& parent_id, uint32_t index) {
  return absl::StrCat(parent_id, ".shard-", index);
}

/// Opens (creating if needed) the SQLite store at `path`, in WAL mode.
absl::StatusOr<std::unique_ptr<JobStore>> OpenSqliteJobStore(const std::string& path);

/// True for a postgresql:// or postgres:// URL (a libpq connection URI).
bool IsPostgresUrl(const std::string& url);
/// Connects to the PostgreSQL database at `url` and migrates its schema
/// (safe when several replicas start at once). Shared by every replica
/// given the same URL (docs/operator_guide.md "Several replicas").
absl::StatusOr<std::unique_ptr<JobStore>> OpenPostgresJobStore(const std::string& url);

}  // namespace nimbus::server
