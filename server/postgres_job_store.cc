// PostgreSQL implementation of JobStore, for several nimbusd replicas on one
// durable queue. Same contract as the SQLite store (server/job_store.h):
// every read-modify-write is one transaction; claims lock the chosen row
// with FOR UPDATE SKIP LOCKED so concurrent claimers on any replica never
// wait for each other and never take the same job; schema migrations run at
// open under a transaction-scoped advisory lock, so replicas starting
// together migrate once. Connections come from a small pool; an operation
// that loses its connection or a deadlock race is retried on a fresh one.
#include <pqxx/pqxx>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/escaping.h"
#include "absl/strings/match.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "server/bounded_text.h"
#include "server/job_store.h"
#include "server/job_store_util.h"
#include "server/postgres_claim_sql.h"
#include "server/postgres_module.h"

namespace nimbus::server {
namespace {

// 1: the schema of SQLite's version 4 (owners, pins, expiry, pokes).
// 2: previews and preview wishes (watchers on other replicas).
// 3: sharded jobs and the result cache (parent_id ... spec_sha256).
// 4: cache hits name their source (cached_from).
// 5: idempotency keys are each principal's own.
// 6: priorities, retries and the fair-share claim order.
constexpr int kSchemaVersion = 6;
// Any fixed 64-bit number: the advisory lock that serialises migrations.
constexpr int64_t kMigrationLockKey = 0x6e696d6275730001;  // "nimbus" + 1
constexpr int kDefaultPageSize = 50;
constexpr int kMaxPageSize = 500;
constexpr size_t kPoolSize = 8;
constexpr int kRetries = 5;
constexpr char kCancelledByRequest[] = "cancelled by request";
constexpr int kCancelledCode = static_cast<int>(absl::StatusCode::kCancelled);
constexpr char kChannel[] = "nimbus_jobs";

// Ids sort bytewise (COLLATE "C") as in SQLite, whatever the database locale.
constexpr char kSchemaV1Sql[] = R"sql(
CREATE TABLE IF NOT EXISTS jobs (
  id TEXT COLLATE "C" PRIMARY KEY NOT NULL,
  name TEXT NOT NULL DEFAULT '',
  state INTEGER NOT NULL,
  spec BYTEA NOT NULL,
  request_id TEXT NOT NULL DEFAULT '',
  create_time BIGINT NOT NULL,
  start_time BIGINT NOT NULL DEFAULT 0,
  end_time BIGINT NOT NULL DEFAULT 0,
  attempts INTEGER NOT NULL DEFAULT 0,
  cancel_requested BOOLEAN NOT NULL DEFAULT FALSE,
  worker_id TEXT NOT NULL DEFAULT '',
  lease_expiry BIGINT NOT NULL DEFAULT 0,
  progress_done BIGINT NOT NULL DEFAULT 0,
  progress_total BIGINT NOT NULL DEFAULT 0,
  error TEXT NOT NULL DEFAULT '',
  result_key TEXT NOT NULL DEFAULT '',
  result_size BIGINT NOT NULL DEFAULT 0,
  result_sha256 TEXT NOT NULL DEFAULT '',
  warnings TEXT NOT NULL DEFAULT '',
  estimated_memory_bytes BIGINT NOT NULL DEFAULT 0,
  error_code INTEGER NOT NULL DEFAULT 0,
  owner TEXT NOT NULL DEFAULT '',
  pinned BOOLEAN NOT NULL DEFAULT FALSE,
  result_expire_time BIGINT NOT NULL DEFAULT 0,
  -- Insertion order: the tie-break among jobs created in the same ms.
  seq BIGSERIAL NOT NULL
);
CREATE INDEX IF NOT EXISTS jobs_owner_create ON jobs (owner, create_time, id);
CREATE INDEX IF NOT EXISTS jobs_state_create ON jobs (state, create_time, id);
CREATE INDEX IF NOT EXISTS jobs_create ON jobs (create_time, id);
CREATE UNIQUE INDEX IF NOT EXISTS jobs_request_id ON jobs (request_id) WHERE request_id <> '';
-- Claiming walks only the live jobs, oldest first, however many have ended.
CREATE INDEX IF NOT EXISTS jobs_claimable ON jobs (create_time, seq) WHERE state IN (1, 2);
CREATE TABLE IF NOT EXISTS pokes (
  seq BIGSERIAL PRIMARY KEY, job_id TEXT NOT NULL, frame BIGINT NOT NULL DEFAULT -1,
  body INTEGER NOT NULL, drag BOOLEAN NOT NULL, x DOUBLE PRECISION NOT NULL,
  y DOUBLE PRECISION NOT NULL, z DOUBLE PRECISION NOT NULL,
  drag_stiffness DOUBLE PRECISION NOT NULL, drag_frames BIGINT NOT NULL);
CREATE INDEX IF NOT EXISTS pokes_job_frame ON pokes (job_id, frame, seq);
)sql";

// The newest preview per job and resolution, and what watchers want.
constexpr char kSchemaV2Sql[] = R"sql(
CREATE TABLE IF NOT EXISTS previews (
  job_id TEXT NOT NULL, resolution INTEGER NOT NULL, sequence BIGINT NOT NULL,
  data BYTEA NOT NULL, PRIMARY KEY (job_id, resolution));
CREATE TABLE IF NOT EXISTS preview_wishes (
  job_id TEXT NOT NULL, resolution INTEGER NOT NULL, interval_ms BIGINT NOT NULL,
  until BIGINT NOT NULL, PRIMARY KEY (job_id, resolution));
)sql";

// Shards (docs/sharding.md) and the spec hash of the result cache.
constexpr char kSchemaV3Sql[] = R"sql(
ALTER TABLE jobs ADD COLUMN IF NOT EXISTS parent_id TEXT COLLATE "C" NOT NULL DEFAULT '';
ALTER TABLE jobs ADD COLUMN IF NOT EXISTS shard_index INTEGER NOT NULL DEFAULT 0;
ALTER TABLE jobs ADD COLUMN IF NOT EXISTS shard_count INTEGER NOT NULL DEFAULT 0;
ALTER TABLE jobs ADD COLUMN IF NOT EXISTS shards_pending INTEGER NOT NULL DEFAULT 0;
ALTER TABLE jobs ADD COLUMN IF NOT EXISTS spec_sha256 TEXT NOT NULL DEFAULT '';
CREATE INDEX IF NOT EXISTS jobs_parent ON jobs (parent_id, shard_index) WHERE parent_id <> '';
CREATE INDEX IF NOT EXISTS jobs_cache ON jobs (spec_sha256, owner, end_time)
  WHERE spec_sha256 <> '' AND state = 3;
)sql";

// Result-cache hits name the job whose result they copy.
constexpr char kSchemaV4Sql[] = R"sql(
ALTER TABLE jobs ADD COLUMN IF NOT EXISTS cached_from TEXT NOT NULL DEFAULT '';
)sql";

// A request_id names a job only among its principal's own: the same key
// from two principals is two jobs, and neither learns of the other.
constexpr char kSchemaV5Sql[] = R"sql(
DROP INDEX IF EXISTS jobs_request_id;
CREATE UNIQUE INDEX IF NOT EXISTS jobs_owner_request_id ON jobs (owner, request_id)
  WHERE request_id <> '';
)sql";

// Priorities (old jobs get the default, 50), the link from a retry to its
// original, and what the claim order reads: claimable QUEUED jobs by
// (priority, owner, age), RUNNING jobs by owner, and each owner's last
// claim (from a sequence, so equal clocks still order); the worker
// registry and the job event log.
constexpr char kSchemaV6Sql[] = R"sql(
ALTER TABLE jobs ADD COLUMN IF NOT EXISTS priority INTEGER NOT NULL DEFAULT 50;
ALTER TABLE jobs ADD COLUMN IF NOT EXISTS retried_from TEXT NOT NULL DEFAULT '';
CREATE INDEX IF NOT EXISTS jobs_claim_order ON jobs (priority, owner, create_time, seq)
  WHERE state = 1 AND NOT cancel_requested AND shards_pending = 0;
CREATE INDEX IF NOT EXISTS jobs_state_owner ON jobs (state, owner);
CREATE TABLE IF NOT EXISTS owner_claims (owner TEXT PRIMARY KEY NOT NULL,
  last_claim BIGINT NOT NULL);
CREATE SEQUENCE IF NOT EXISTS owner_claim_seq;
CREATE TABLE IF NOT EXISTS workers (replica_id TEXT COLLATE "C" PRIMARY KEY NOT NULL,
  host TEXT NOT NULL, version TEXT NOT NULL, start_time BIGINT NOT NULL,
  worker_slots INTEGER NOT NULL, threads_per_job INTEGER NOT NULL,
  jobs_running INTEGER NOT NULL, last_heartbeat BIGINT NOT NULL);
CREATE TABLE IF NOT EXISTS job_events (job_id TEXT COLLATE "C" NOT NULL, seq BIGINT NOT NULL,
  time BIGINT NOT NULL, kind TEXT NOT NULL, fields TEXT NOT NULL,
  PRIMARY KEY (job_id, seq));
)sql";

// Migrations in order: kMigrations[v - 1] takes the schema to version v.
constexpr const char* kMigrations[] = {kSchemaV1Sql, kSchemaV2Sql, kSchemaV3Sql,
                                       kSchemaV4Sql, kSchemaV5Sql, kSchemaV6Sql};
static_assert(std::size(kMigrations) == kSchemaVersion);

// The columns RowToRecord reads, in order. Text a reader could make huge is
// cut in SQL, as in the SQLite store; the spec travels as hex text.
#define NIMBUS_PG_COLUMNS                                                                  \
  "id, substr(name, 1, 256), state, encode(spec, 'hex'), request_id, create_time, "        \
  "start_time, end_time, attempts, cancel_requested, worker_id, lease_expiry, "            \
  "progress_done, progress_total, substr(error, 1, 4200), result_key, result_size, "       \
  "result_sha256, substr(warnings, 1, 16500), estimated_memory_bytes, error_code, owner, " \
  "pinned, result_expire_time, parent_id, shard_index, shard_count, shards_pending, "      \
  "spec_sha256, cached_from, priority, retried_from"

// 64-bit counters are stored as the same bits in a BIGINT.
int64_t ToDb(uint64_t v) { return static_cast<int64_t>(v); }
uint64_t FromDb(const pqxx::field& f) { return static_cast<uint64_t>(f.as<int64_t>()); }

std::string HexToBytes(const std::string& hex) { return absl::HexStringToBytes(hex); }

JobRecord RowToRecord(const pqxx::row& row) {
  JobRecord r;
  r.id = row[0].as<std::string>();
  r.name = row[1].as<std::string>();
  r.state = static_cast<JobState>(row[2].as<int>());
  r.spec = HexToBytes(row[3].as<std::string>());
  r.request_id = row[4].as<std::string>();
  r.create_time = row[5].as<int64_t>();
  r.start_time = row[6].as<int64_t>();
  r.end_time = row[7].as<int64_t>();
  r.attempts = static_cast<uint32_t>(row[8].as<int64_t>());
  r.cancel_requested = row[9].as<bool>();
  r.worker_id = row[10].as<std::string>();
  r.lease_expiry = row[11].as<int64_t>();
  r.progress_done = FromDb(row[12]);
  r.progress_total = FromDb(row[13]);
  r.error = row[14].as<std::string>();
  r.result_key = row[15].as<std::string>();
  r.result_size = FromDb(row[16]);
  r.result_sha256 = row[17].as<std::string>();
  r.warnings = row[18].as<std::string>();
  r.estimated_memory_bytes = FromDb(row[19]);
  r.error_code = row[20].as<int>();
  r.owner = row[21].as<std::string>();
  r.pinned = row[22].as<bool>();
  r.result_expire_time = row[23].as<int64_t>();
  r.parent_id = row[24].as<std::string>();
  r.shard_index = static_cast<uint32_t>(row[25].as<int64_t>());
  r.shard_count = static_cast<uint32_t>(row[26].as<int64_t>());
  r.shards_pending = static_cast<uint32_t>(row[27].as<int64_t>());
  r.spec_sha256 = row[28].as<std::string>();
  r.cached_from = row[29].as<std::string>();
  r.priority = row[30].as<int>();
  r.retried_from = row[31].as<std::string>();
  return r;
}

std::string StateName(JobState s) {
  switch (s) {
    case JobState::kQueued: return "QUEUED";
    case JobState::kRunning: return "RUNNING";
    case JobState::kSucceeded: return "SUCCEEDED";
    case JobState::kFailed: return "FAILED";
    case JobState::kCancelled: return "CANCELLED";
  }
  return absl::StrCat("state ", static_cast<int>(s));
}

// An early return out of a transaction body: the status to hand back.
struct Abort {
  absl::Status status;
};

}  // namespace

class PostgresJobStore final : public JobStore {
 public:
  static absl::StatusOr<std::unique_ptr<JobStore>> Open(const std::string& url);
  ~PostgresJobStore() override { SetChangeListener(nullptr); }

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
  absl::StatusOr<OwnerUsage> Usage(const std::string& owner) override;
  absl::StatusOr<JobRecord> SetPinned(const std::string& id, bool pinned) override;
  absl::Status Delete(const std::string& id) override;
  absl::StatusOr<std::vector<JobRecord>> ListExpiring(TimeMs cutoff, int limit) override;
  absl::Status MarkResultExpired(const std::string& id, TimeMs now) override;
  absl::StatusOr<std::vector<std::string>> SpecsInUse() override;
  absl::StatusOr<PokeRecord> AddPoke(const std::string& id, const PokeRecord& poke) override;
  absl::StatusOr<std::vector<PokeRecord>> TakePokes(const std::string& id,
                                                    const std::string& worker_id,
                                                    int64_t frame) override;
  void SetChangeListener(JobChangeListener listener) override;
  absl::Status WishPreviews(const std::string& id, const std::vector<PreviewWish>& wishes,
                            TimeMs until) override;
  absl::StatusOr<std::vector<PreviewWish>> PreviewWishes(const std::string& id,
                                                         TimeMs now) override;
  absl::Status PutPreview(const std::string& id, uint32_t resolution, uint64_t sequence,
                          const std::string& preview) override;
  absl::StatusOr<std::string> LatestPreview(const std::string& id, uint32_t resolution) override;
  absl::StatusOr<std::vector<JobRecord>> ListShards(const std::string& parent_id) override;
  absl::StatusOr<std::optional<JobRecord>> FindCached(const std::string& spec_sha256,
                                                      const std::string& owner) override;
  absl::StatusOr<JobRecord> SetPriority(const std::string& id, int priority) override;
  // WorkerRegistry and JobEventLog.
  absl::Status RegisterWorker(const WorkerInfo& info) override;
  absl::Status RenewWorker(const std::string& replica_id, uint32_t jobs_running,
                           int64_t now) override;
  absl::Status UnregisterWorker(const std::string& replica_id) override;
  absl::StatusOr<int> PruneWorkers(int64_t cutoff) override;
  absl::StatusOr<std::vector<WorkerInfo>> ListWorkers() override;
  absl::Status AppendEvent(const std::string& job_id, const JobEvent& event) override;
  absl::StatusOr<JobEventPage> ListEvents(const std::string& job_id, int64_t after,
                                          int limit) override;

 private:
  // Appends to `job_id`'s event log inside `t`; appends to one job's log
  // take turns (a transaction-scoped advisory lock on the job id).
  static void AppendEventIn(pqxx::work& t, const std::string& job_id, const JobEvent& event);
  // The feed: LISTEN on a connection of its own, reconnecting when lost.
  void ListenLoop();
  void Deliver(const std::string& payload);
  explicit PostgresJobStore(std::string url) : url_(std::move(url)) {}

  // Runs `body` in one transaction on a pooled connection and commits; an
  // Abort thrown by the body rolls back and returns its status. Lost
  // connections and deadlock or serialisation races are retried.
  template <typename T>
  absl::StatusOr<T> InTxn(const char* what, const std::function<T(pqxx::work&)>& body);
  absl::Status InTxnVoid(const char* what, const std::function<void(pqxx::work&)>& body);

  absl::StatusOr<std::unique_ptr<pqxx::connection>> Acquire();
  void Return(std::unique_ptr<pqxx::connection> c);
  absl::Status Migrate();
  absl::Status Error(const char* what, const std::exception& e) const;

  // Row helpers, inside a transaction.
  static std::optional<JobRecord> Load(pqxx::work& t, const std::string& id, bool lock);
  static JobRecord LoadExisting(pqxx::work& t, const std::string& id, bool lock);
  static void CheckClaim(pqxx::work& t, const std::string& id, const std::string& worker_id);
  static void CancelOrphans(pqxx::work& t, TimeMs now, bool lapsed_only);
  static void GiveUp(pqxx::work& t, const std::string& id, uint32_t attempts, TimeMs now);
  // The next job by the claim order (docs/operator_guide.md "Claim
  // order"), locked FOR UPDATE, with its attempts; rows other claimers
  // hold are skipped. nullopt when nothing is claimable.
  static std::optional<std::pair<std::string, uint32_t>> PickClaimable(pqxx::work& t, TimeMs now);
  // The owners with claimable QUEUED jobs at `priority`, best turn first.
  static std::vector<std::pair<std::string, OwnerTurn>> RankOwners(pqxx::work& t, int64_t priority);
  // A shard's end reaches its parent (docs/sharding.md): success counts
  // down shards_pending; failure or cancellation ends the parent and
  // stops its other shards. Nothing for an ordinary job.
  static void PropagateShardEnd(pqxx::work& t, const std::string& id, TimeMs now);
  // Cancels the QUEUED shards of `parent_id` and flags the RUNNING ones.
  static void StopShards(pqxx::work& t, const std::string& parent_id, TimeMs now,
                         const std::string& error);
  static void Notify(pqxx::work& t, const std::string& id, bool claimable = false);

  struct AttemptEnd {
    std::string error;
    int code = 0;
  };
  absl::Status GiveBack(const std::string& id, const std::string& worker_id,
                        const std::optional<AttemptEnd>& attempt);

  const std::string url_;
  std::mutex pool_mu_;
  std::condition_variable pool_cv_;
  std::vector<std::unique_ptr<pqxx::connection>> idle_;
  size_t open_ = 0;

  std::mutex listen_mu_;  // guards listener_ and listen_thread_
  JobChangeListener listener_;
  std::thread listen_thread_;
  std::atomic<bool> stop_listening_{false};
};

absl::Status PostgresJobStore::Error(const char* what, const std::exception& e) const {
  absl::StatusCode code = absl::StatusCode::kInternal;
  if (dynamic_cast<const pqxx::broken_connection*>(&e) != nullptr ||
      dynamic_cast<const pqxx::transaction_rollback*>(&e) != nullptr ||
      dynamic_cast<const pqxx::in_doubt_error*>(&e) != nullptr) {
    code = absl::StatusCode::kUnavailable;  // Retryable.
  } else if (dynamic_cast<const pqxx::unique_violation*>(&e) != nullptr) {
    code = absl::StatusCode::kAlreadyExists;
  } else if (dynamic_cast<const pqxx::disk_full*>(&e) != nullptr) {
    code = absl::StatusCode::kResourceExhausted;
  } else if (dynamic_cast<const pqxx::insufficient_privilege*>(&e) != nullptr) {
    code = absl::StatusCode::kPermissionDenied;
  }
  std::string msg = e.what();
  while (!msg.empty() && (msg.back() == '\n' || msg.back() == ' ')) msg.pop_back();
  return absl::Status(code, absl::StrCat("job store ", RedactUrl(url_), ": ", what, ": ",
                                         BoundText(msg, 1024)));
}

absl::StatusOr<std::unique_ptr<pqxx::connection>> PostgresJobStore::Acquire() {
  {
    std::unique_lock<std::mutex> lock(pool_mu_);
    pool_cv_.wait(lock, [&] { return !idle_.empty() || open_ < kPoolSize; });
    if (!idle_.empty()) {
      std::unique_ptr<pqxx::connection> c = std::move(idle_.back());
      idle_.pop_back();
      return c;
    }
    ++open_;
  }
  try {
    return std::make_unique<pqxx::connection>(url_);
  } catch (const std::exception& e) {
    {
      std::lock_guard<std::mutex> lock(pool_mu_);
      --open_;
    }
    pool_cv_.notify_one();
    return Error("connect", e);
  }
}

void PostgresJobStore::Return(std::unique_ptr<pqxx::connection> c) {
  {
    std::lock_guard<std::mutex> lock(pool_mu_);
    if (c != nullptr && c->is_open()) {
      idle_.push_back(std::move(c));
    } else {
      --open_;  // Dropped: a fresh one is opened on demand.
    }
  }
  pool_cv_.notify_one();
}

template <typename T>
absl::StatusOr<T> PostgresJobStore::InTxn(const char* what,
                                          const std::function<T(pqxx::work&)>& body) {
  absl::Status last;
  for (int attempt = 0; attempt < kRetries; ++attempt) {
    absl::StatusOr<std::unique_ptr<pqxx::connection>> c = Acquire();
    if (!c.ok()) return c.status();
    bool keep = true;
    try {
      pqxx::work t(**c);
      T out = body(t);
      t.commit();
      Return(std::move(*c));
      return out;
    } catch (const Abort& a) {
      Return(std::move(*c));
      return a.status;
    } catch (const pqxx::broken_connection& e) {
      keep = false;
      last = Error(what, e);
    } catch (const pqxx::transaction_rollback& e) {
      last = Error(what, e);  // Deadlock or serialisation race: run again.
    } catch (const pqxx::in_doubt_error& e) {
      Return(nullptr);
      return Error(what, e);  // Unknown whether it committed: do not repeat.
    } catch (const std::exception& e) {
      Return(std::move(*c));
      return Error(what, e);
    }
    Return(keep ? std::move(*c) : nullptr);
  }
  return last;
}

absl::Status PostgresJobStore::InTxnVoid(const char* what,
                                         const std::function<void(pqxx::work&)>& body) {
  return InTxn<bool>(what, [&](pqxx::work& t) {
           body(t);
           return true;
         })
      .status();
}

absl::StatusOr<std::unique_ptr<JobStore>> PostgresJobStore::Open(const std::string& url) {
  std::unique_ptr<PostgresJobStore> store(new PostgresJobStore(url));
  if (absl::Status s = store->Migrate(); !s.ok()) return s;
  return std::unique_ptr<JobStore>(std::move(store));
}

absl::Status PostgresJobStore::Migrate() {
  return InTxnVoid("migrate the schema", [](pqxx::work& t) {
    // Held to the end of this transaction: a second replica starting now
    // waits here, then finds the schema current.
    t.exec_params("SELECT pg_advisory_xact_lock($1)", kMigrationLockKey);
    t.exec("CREATE TABLE IF NOT EXISTS nimbus_schema (version INTEGER NOT NULL)");
    pqxx::result v = t.exec("SELECT version FROM nimbus_schema");
    int version = v.empty() ? 0 : v[0][0].as<int>();
    if (version > kSchemaVersion) {
      throw Abort{absl::FailedPreconditionError(
          absl::StrCat("job store: schema version ", version,
                       " is newer than this binary supports (", kSchemaVersion, ")"))};
    }
    if (version == kSchemaVersion) return;
    for (; version < kSchemaVersion; ++version) t.exec(kMigrations[version]);
    t.exec("DELETE FROM nimbus_schema");
    t.exec_params("INSERT INTO nimbus_schema (version) VALUES ($1)", kSchemaVersion);
  });
}

std::optional<JobRecord> PostgresJobStore::Load(pqxx::work& t, const std::string& id, bool lock) {
  pqxx::result r = t.exec_params(
      lock ? "SELECT " NIMBUS_PG_COLUMNS " FROM jobs WHERE id = $1 FOR UPDATE"
           : "SELECT " NIMBUS_PG_COLUMNS " FROM jobs WHERE id = $1",
      id);
  if (r.empty()) return std::nullopt;
  return RowToRecord(r[0]);
}

JobRecord PostgresJobStore::LoadExisting(pqxx::work& t, const std::string& id, bool lock) {
  std::optional<JobRecord> r = Load(t, id, lock);
  if (!r.has_value())
    throw Abort{absl::NotFoundError(absl::StrCat("job \"", EchoId(id), "\" not found"))};
  return std::move(*r);
}

void PostgresJobStore::CheckClaim(pqxx::work& t, const std::string& id,
                                  const std::string& worker_id) {
  pqxx::result r =
      t.exec_params("SELECT state, worker_id FROM jobs WHERE id = $1 FOR UPDATE", id);
  if (r.empty())
    throw Abort{absl::NotFoundError(absl::StrCat("job \"", EchoId(id), "\" not found"))};
  const auto state = static_cast<JobState>(r[0][0].as<int>());
  const std::string holder = r[0][1].as<std::string>();
  if (state != JobState::kRunning) {
    throw Abort{absl::FailedPreconditionError(
        absl::StrCat("job \"", id, "\" is ", StateName(state), ", not RUNNING"))};
  }
  if (holder != worker_id) {
    throw Abort{absl::FailedPreconditionError(absl::StrCat(
        "job \"", id, "\" is claimed by worker \"", holder, "\", not \"", worker_id, "\""))};
  }
}

// Tells every replica listening that `id` changed (delivered on commit):
// the payload is "q ID" when the job may be claimable, "c ID" otherwise.
void PostgresJobStore::Notify(pqxx::work& t, const std::string& id, bool claimable) {
  t.exec_params("SELECT pg_notify($1, $2)", std::string(kChannel),
                absl::StrCat(claimable ? "q " : "c ", id));
}

namespace {
class Receiver final : public pqxx::notification_receiver {
 public:
  Receiver(pqxx::connection_base& c, std::function<void(const std::string&)> deliver)
      : pqxx::notification_receiver(c, kChannel), deliver_(std::move(deliver)) {}
  void operator()(const std::string& payload, int) override { deliver_(payload); }

 private:
  std::function<void(const std::string&)> deliver_;
};
}  // namespace

void PostgresJobStore::SetChangeListener(JobChangeListener listener) {
  std::thread old;
  {
    std::lock_guard<std::mutex> lock(listen_mu_);
    if (listener != nullptr) {
      listener_ = std::move(listener);
      if (!listen_thread_.joinable()) {
        stop_listening_ = false;
        listen_thread_ = std::thread([this] { ListenLoop(); });
      }
      return;
    }
    stop_listening_ = true;
    old = std::move(listen_thread_);
  }
  if (old.joinable()) old.join();
  std::lock_guard<std::mutex> lock(listen_mu_);
  listener_ = nullptr;
}

void PostgresJobStore::Deliver(const std::string& payload) {
  JobChange change;
  change.claimable = payload.empty() || payload[0] == 'q';
  change.preview = !payload.empty() && payload[0] == 'p';
  if (payload.size() > 2) change.job_id = payload.substr(2);
  JobChangeListener listener;
  {
    std::lock_guard<std::mutex> lock(listen_mu_);
    listener = listener_;
  }
  if (listener != nullptr) listener(change);
}

void PostgresJobStore::ListenLoop() {
  while (!stop_listening_) {
    try {
      pqxx::connection c(url_);
      Receiver receiver(c, [this](const std::string& p) { Deliver(p); });
      // (Re)connected: whatever happened meanwhile was not heard.
      Deliver("q");
      // Short waits so a stop request is seen promptly.
      while (!stop_listening_) c.await_notification(0, 100'000);
    } catch (const std::exception&) {
      for (int i = 0; i < 10 && !stop_listening_; ++i)
        std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
  }
}

void PostgresJobStore::CancelOrphans(pqxx::work& t, TimeMs now, bool lapsed_only) {
  // SKIP LOCKED: a row another transaction holds is not an orphan of ours
  // to finish now; a later claim will see it.
  t.exec_params(
      lapsed_only
          ? "UPDATE jobs SET end_time = $1, state = 5, error = $2, error_code = $3, "
            "worker_id = '', lease_expiry = 0 WHERE id IN (SELECT id FROM jobs WHERE state = 2 "
            "AND cancel_requested AND lease_expiry < $1 FOR UPDATE SKIP LOCKED)"
          : "UPDATE jobs SET end_time = $1, state = 5, error = $2, error_code = $3, "
            "worker_id = '', lease_expiry = 0 WHERE state = 2 AND cancel_requested",
      now, std::string(kCancelledByRequest), kCancelledCode);
}

void PostgresJobStore::GiveUp(pqxx::work& t, const std::string& id, uint32_t attempts,
                              TimeMs now) {
  t.exec_params(
      "UPDATE jobs SET state = 4, end_time = $1, worker_id = '', lease_expiry = 0, "
      "error = CASE WHEN error = '' THEN $2 ELSE $3 || error END, "
      "error_code = CASE WHEN error_code <> 0 THEN error_code ELSE $4 END WHERE id = $5",
      now,
      absl::StrCat("gave up after ", attempts,
                   " attempts: none recorded an end (the worker stopped or lost its claim)"),
      absl::StrCat("gave up after ", attempts, " attempts; the last one: "),
      static_cast<int>(absl::StatusCode::kInternal), id);
}

std::optional<std::pair<std::string, uint32_t>> PostgresJobStore::PickClaimable(pqxx::work& t,
                                                                                TimeMs now) {
  using Pick = std::optional<std::pair<std::string, uint32_t>>;
  const auto picked = [](const pqxx::result& r) {
    return Pick(std::pair(r[0][0].as<std::string>(), static_cast<uint32_t>(r[0][1].as<int64_t>())));
  };
  // Priorities from the top; a level whose rows other claimers hold
  // all is passed over for the next one down.
  int64_t below = kAnyPriority;
  for (bool first = true;; first = false) {
    pqxx::result top = t.exec_params(kTopPrioritySql, below);
    // -1: no claimable QUEUED job (below `below`).
    const int64_t level = top.empty() ? -1 : top[0][0].as<int64_t>();
    if (first) {
      // A RUNNING job whose lease lapsed goes first unless a queued job
      // has a higher priority; running jobs are few (one per worker).
      pqxx::result lapsed = t.exec_params(kLapsedLeaseSql, now, level);
      if (!lapsed.empty()) return picked(lapsed);
    }
    if (level < 0) return Pick();
    for (const auto& [owner, turn] : RankOwners(t, level)) {
      pqxx::result r = t.exec_params(kOwnersOldestSql, level, owner);
      if (!r.empty()) return picked(r);
    }
    below = level;
  }
}

std::vector<std::pair<std::string, OwnerTurn>> PostgresJobStore::RankOwners(pqxx::work& t,
                                                                            int64_t priority) {
  // The cost grows with the owners at `priority`, not with their jobs.
  std::vector<std::pair<std::string, OwnerTurn>> owners;
  for (const pqxx::row& r : t.exec_params(kRankOwnersSql, priority)) {
    OwnerTurn turn;
    turn.create_time = r[1].as<int64_t>();
    turn.seq = r[2].as<int64_t>();
    turn.job_id = r[3].as<std::string>();
    turn.running = static_cast<uint64_t>(r[4].as<int64_t>());
    turn.last_claim = r[5].as<int64_t>();
    owners.emplace_back(r[0].as<std::string>(), std::move(turn));
  }
  std::stable_sort(owners.begin(), owners.end(),
                   [](const auto& a, const auto& b) { return a.second < b.second; });
  return owners;
}

absl::StatusOr<JobRecord> PostgresJobStore::SetPriority(const std::string& id, int priority) {
  if (absl::Status s = CheckPriority(priority); !s.ok()) return s;
  return InTxn<JobRecord>("set a job's priority", [&](pqxx::work& t) {
    const JobRecord r = LoadExisting(t, id, /*lock=*/true);
    if (r.state != JobState::kQueued)
      throw Abort{
          absl::FailedPreconditionError(absl::StrCat("job \"", id, "\" is ", StateName(r.state),
                                                     ": only a QUEUED job's priority can change"))};
    // A sharded parent waits QUEUED for its shards: the queued ones follow.
    t.exec_params("UPDATE jobs SET priority = $1 WHERE id = $2 OR (parent_id = $2 AND state = 1)",
                  priority, id);
    Notify(t, id, /*claimable=*/true);
    return LoadExisting(t, id, false);
  });
}

absl::Status PostgresJobStore::RegisterWorker(const WorkerInfo& w) {
  return InTxnVoid("register a replica", [&](pqxx::work& t) {
    t.exec_params(
        "INSERT INTO workers (replica_id, host, version, start_time, worker_slots, "
        "threads_per_job, jobs_running, last_heartbeat) VALUES ($1, $2, $3, $4, $5, $6, $7, $8) "
        "ON CONFLICT (replica_id) DO UPDATE SET host = EXCLUDED.host, "
        "version = EXCLUDED.version, start_time = EXCLUDED.start_time, "
        "worker_slots = EXCLUDED.worker_slots, threads_per_job = EXCLUDED.threads_per_job, "
        "jobs_running = EXCLUDED.jobs_running, last_heartbeat = EXCLUDED.last_heartbeat",
        w.replica_id, w.host, w.version, w.start_time, int64_t{w.worker_slots},
        int64_t{w.threads_per_job}, int64_t{w.jobs_running}, w.last_heartbeat);
  });
}

absl::Status PostgresJobStore::RenewWorker(const std::string& replica_id, uint32_t jobs_running,
                                           int64_t now) {
  return InTxnVoid("renew a replica", [&](pqxx::work& t) {
    pqxx::result r = t.exec_params(
        "UPDATE workers SET jobs_running = $2, last_heartbeat = $3 WHERE replica_id = $1",
        replica_id, int64_t{jobs_running}, now);
    if (r.affected_rows() == 0)
      throw Abort{
          absl::NotFoundError(absl::StrCat("replica \"", replica_id, "\" is not registered"))};
  });
}

absl::Status PostgresJobStore::UnregisterWorker(const std::string& replica_id) {
  return InTxnVoid("unregister a replica", [&](pqxx::work& t) {
    t.exec_params("DELETE FROM workers WHERE replica_id = $1", replica_id);
  });
}

absl::StatusOr<int> PostgresJobStore::PruneWorkers(int64_t cutoff) {
  return InTxn<int>("drop lost replicas", [&](pqxx::work& t) {
    return static_cast<int>(
        t.exec_params("DELETE FROM workers WHERE last_heartbeat < $1", cutoff).affected_rows());
  });
}

absl::StatusOr<std::vector<WorkerInfo>> PostgresJobStore::ListWorkers() {
  return InTxn<std::vector<WorkerInfo>>("list replicas", [&](pqxx::work& t) {
    std::vector<WorkerInfo> out;
    for (const pqxx::row& r :
         t.exec("SELECT replica_id, host, version, start_time, worker_slots, threads_per_job, "
                "jobs_running, last_heartbeat FROM workers ORDER BY replica_id"))
      out.push_back({r[0].as<std::string>(), r[1].as<std::string>(), r[2].as<std::string>(),
                     r[3].as<int64_t>(), r[4].as<uint32_t>(), r[5].as<uint32_t>(),
                     r[6].as<uint32_t>(), r[7].as<int64_t>()});
    return out;
  });
}

void PostgresJobStore::AppendEventIn(pqxx::work& t, const std::string& job_id,
                                     const JobEvent& event) {
  t.exec_params("SELECT pg_advisory_xact_lock(hashtextextended($1, 43))", job_id);
  // The newest kMaxEventsPerJob stay; seqs stay contiguous, so the first
  // one kept tells how many were dropped.
  t.exec_params(
      "WITH added AS (INSERT INTO job_events (job_id, seq, time, kind, fields) "
      "SELECT $1, coalesce(max(seq), 0) + 1, $2, $3, $4 FROM job_events WHERE job_id = $1 "
      "RETURNING seq) "
      "DELETE FROM job_events WHERE job_id = $1 AND seq <= (SELECT seq FROM added) - $5",
      job_id, event.time, BoundText(event.kind, kMaxEventFieldBytes),
      EncodeEventFields(event.fields), kMaxEventsPerJob);
}

absl::Status PostgresJobStore::AppendEvent(const std::string& job_id, const JobEvent& event) {
  return InTxnVoid("append a job event", [&](pqxx::work& t) { AppendEventIn(t, job_id, event); });
}

absl::StatusOr<JobEventPage> PostgresJobStore::ListEvents(const std::string& job_id, int64_t after,
                                                          int limit) {
  limit = std::clamp(limit <= 0 ? kDefaultPageSize : limit, 1, kMaxPageSize);
  return InTxn<JobEventPage>("list job events", [&](pqxx::work& t) {
    JobEventPage page;
    page.dropped =
        t.exec_params1("SELECT coalesce(min(seq), 1) - 1 FROM job_events WHERE job_id = $1",
                       job_id)[0]
            .as<int64_t>();
    for (const pqxx::row& r : t.exec_params(
             "SELECT seq, time, kind, fields FROM job_events WHERE job_id = $1 AND seq > $2 "
             "ORDER BY seq LIMIT $3",
             job_id, after, limit + 1)) {
      if (static_cast<int>(page.events.size()) == limit) {
        page.next_after = page.events.back().seq;
        break;
      }
      page.events.push_back({r[0].as<int64_t>(), r[1].as<int64_t>(), r[2].as<std::string>(),
                             DecodeEventFields(r[3].as<std::string>())});
    }
    return page;
  });
}

absl::StatusOr<JobRecord> PostgresJobStore::Create(const NewJob& job, TimeMs now) {
  if (job.name.size() > kMaxJobNameBytes)
    return absl::InvalidArgumentError(absl::StrCat("name: must be at most ", kMaxJobNameBytes,
                                                   " bytes, got ", job.name.size()));
  if (absl::Status s = CheckPriority(job.priority); !s.ok()) return s;
  return InTxn<JobRecord>("create a job", [&](pqxx::work& t) {
    auto existing_for_key = [&]() -> std::optional<JobRecord> {
      if (job.request_id.empty()) return std::nullopt;
      pqxx::result r = t.exec_params("SELECT " NIMBUS_PG_COLUMNS
                                     " FROM jobs WHERE owner = $1 AND request_id = $2",
                                     job.owner, job.request_id);
      if (r.empty()) return std::nullopt;
      JobRecord existing = RowToRecord(r[0]);
      if (existing.spec != job.spec)
        throw Abort{absl::AlreadyExistsError(
            absl::StrCat("request_id ", EchoId(job.request_id),
                         " was already used for another spec (job ", existing.id, ")"))};
      return existing;
    };
    if (std::optional<JobRecord> e = existing_for_key()) return std::move(*e);
    // ON CONFLICT waits for a concurrent insert of the same key or id and
    // then skips; the key lookup below sees the winner's row.
    if (job.shard_count > 1 && !job.cached_from.empty())
      throw Abort{absl::InvalidArgumentError("a result-cache hit cannot be sharded")};
    const std::string spec_hex = absl::BytesToHexString(job.spec);
    const int64_t shards = job.shard_count > 1 ? job.shard_count : 0;
    pqxx::result ins = t.exec_params(
        "INSERT INTO jobs (id, name, state, spec, request_id, create_time, progress_total, "
        "warnings, estimated_memory_bytes, owner, shard_count, shards_pending, spec_sha256, "
        "priority, retried_from) "
        "VALUES ($1, $2, 1, decode($3, 'hex'), $4, $5, $6, $7, $8, $9, $10, $10, $11, $12, $13) "
        "ON CONFLICT DO NOTHING RETURNING " NIMBUS_PG_COLUMNS,
        job.id, job.name, spec_hex, job.request_id, now, ToDb(job.progress_total),
        BoundText(job.warnings, kMaxWarningsBytes), ToDb(job.estimated_memory_bytes), job.owner,
        shards, job.spec_sha256, job.priority, job.retried_from);
    if (!ins.empty()) {
      if (!job.submitted_by.empty()) AppendEventIn(t, job.id, SubmittedEvent(job, now));
      // The shards, in index order (insertion order breaks create_time ties).
      for (int64_t k = 0; k < shards; ++k) {
        t.exec_params(
            "INSERT INTO jobs (id, name, state, spec, create_time, progress_total, "
            "estimated_memory_bytes, owner, parent_id, shard_index, shard_count, spec_sha256, "
            "priority) VALUES ($1, $2, 1, decode($3, 'hex'), $4, $5, $6, $7, $8, $9, $10, $11, "
            "$12)",
            ShardJobId(job.id, uint32_t(k)), job.name, spec_hex, now, ToDb(job.progress_total),
            ToDb(job.estimated_memory_bytes), job.owner, job.id, k, shards, job.spec_sha256,
            job.priority);
      }
      if (!job.cached_from.empty()) {
        // A cache hit is born finished, with the copied result.
        const Completion& c = job.cached_result;
        pqxx::result done = t.exec_params(
            "UPDATE jobs SET state = 3, start_time = $1, end_time = $1, "
            "progress_done = progress_total, result_key = $2, result_size = $3, "
            "result_sha256 = $4, cached_from = $5 WHERE id = $6 RETURNING " NIMBUS_PG_COLUMNS,
            now, c.result_key, ToDb(c.result_size), c.result_sha256, job.cached_from, job.id);
        Notify(t, job.id);
        return RowToRecord(done[0]);
      }
      Notify(t, job.id, /*claimable=*/true);
      return RowToRecord(ins[0]);
    }
    if (std::optional<JobRecord> e = existing_for_key()) return std::move(*e);
    throw Abort{absl::AlreadyExistsError(absl::StrCat("job \"", job.id, "\" already exists"))};
  });
}

absl::StatusOr<JobRecord> PostgresJobStore::Get(const std::string& id) {
  return InTxn<JobRecord>("get a job",
                          [&](pqxx::work& t) { return LoadExisting(t, id, false); });
}

absl::StatusOr<ListPage> PostgresJobStore::List(const ListOptions& options) {
  int page_size = options.page_size == 0 ? kDefaultPageSize : options.page_size;
  page_size = std::clamp(page_size, 1, kMaxPageSize);
  const bool has_cursor = !options.page_token.empty();
  TimeMs cursor_time = 0;
  std::string cursor_id;
  if (has_cursor) {
    if (absl::Status s = DecodePageToken(options.page_token, &cursor_time, &cursor_id); !s.ok())
      return s;
  }
  // Unused filters are switched off by their flag parameter.
  const char* sql = "SELECT " NIMBUS_PG_COLUMNS
                    " FROM jobs WHERE ($1 = 0 OR state = $1) "
                    "AND (NOT $2 OR (create_time, id) < ($3, $4)) "
                    "AND (NOT $5 OR owner = $6) AND ($8 OR parent_id = '') "
                    "ORDER BY create_time DESC, id DESC LIMIT $7";
  return InTxn<ListPage>("list jobs", [&](pqxx::work& t) {
    pqxx::result rows = t.exec_params(
        sql, options.state.has_value() ? static_cast<int>(*options.state) : 0, has_cursor,
        cursor_time, cursor_id, options.owner.has_value(), options.owner.value_or(""),
        page_size + 1, options.include_shards);
    ListPage page;
    uint64_t bytes = 0;
    for (const pqxx::row& row : rows) {
      JobRecord r = RowToRecord(row);
      const uint64_t more = ViewBytes(r);
      if (static_cast<int>(page.jobs.size()) == page_size ||
          (!page.jobs.empty() && bytes + more > options.max_bytes)) {
        const JobRecord& last = page.jobs.back();
        page.next_page_token = EncodePageToken(last.create_time, last.id);
        break;
      }
      bytes += more;
      page.jobs.push_back(std::move(r));
    }
    return page;
  });
}

absl::StatusOr<std::optional<JobRecord>> PostgresJobStore::ClaimNext(
    const std::string& worker_id, TimeMs now, TimeMs lease_ms, uint32_t max_attempts,
    std::vector<JobRecord>* given_up) {
  std::vector<JobRecord> gave_up;
  absl::StatusOr<std::optional<JobRecord>> out =
      InTxn<std::optional<JobRecord>>("claim a job", [&](pqxx::work& t) {
        gave_up.clear();
        CancelOrphans(t, now, /*lapsed_only=*/true);
        while (true) {
          // The next row by the claim order that nobody else is claiming.
          std::optional<std::pair<std::string, uint32_t>> pick = PickClaimable(t, now);
          if (!pick.has_value()) return std::optional<JobRecord>();
          const std::string& id = pick->first;
          const uint32_t attempts = pick->second;
          if (max_attempts > 0 && attempts >= max_attempts) {
            GiveUp(t, id, attempts, now);
            PropagateShardEnd(t, id, now);
            Notify(t, id);
            gave_up.push_back(LoadExisting(t, id, false));
            continue;
          }
          const JobRecord before = LoadExisting(t, id, false);
          if (before.state == JobState::kRunning)  // its worker stopped heartbeating
            AppendEventIn(t, id,
                          {0,
                           now,
                           "lease_lost",
                           {{"worker", before.worker_id},
                            {"attempt", absl::StrCat(before.attempts)},
                            {"lease_expiry", absl::StrCat(before.lease_expiry)}}});
          // progress_done restarts with the new attempt; the total stays.
          pqxx::result claimed = t.exec_params(
              "UPDATE jobs SET state = 2, worker_id = $1, lease_expiry = $2, start_time = $3, "
              "attempts = attempts + 1, progress_done = 0 WHERE id = $4 "
              "RETURNING " NIMBUS_PG_COLUMNS,
              worker_id, now + lease_ms, now, id);
          t.exec_params(
              "INSERT INTO owner_claims (owner, last_claim) "
              "VALUES ($1, nextval('owner_claim_seq')) "
              "ON CONFLICT (owner) DO UPDATE SET last_claim = EXCLUDED.last_claim",
              claimed[0][21].as<std::string>());
          AppendEventIn(t, id,
                        {0,
                         now,
                         "claimed",
                         {{"worker", worker_id}, {"attempt", absl::StrCat(attempts + 1)}}});
          Notify(t, id);
          return std::optional<JobRecord>(RowToRecord(claimed[0]));
        }
      });
  if (out.ok() && given_up != nullptr)
    given_up->insert(given_up->end(), gave_up.begin(), gave_up.end());
  return out;
}

absl::StatusOr<bool> PostgresJobStore::Heartbeat(const std::string& id,
                                                 const std::string& worker_id, TimeMs now,
                                                 TimeMs lease_ms, uint64_t progress_done,
                                                 uint64_t progress_total) {
  return InTxn<bool>("heartbeat", [&](pqxx::work& t) {
    pqxx::result r = t.exec_params(
        "UPDATE jobs SET lease_expiry = $1, progress_done = $2, progress_total = $3 "
        "WHERE id = $4 AND state = 2 AND worker_id = $5 RETURNING cancel_requested",
        now + lease_ms, ToDb(progress_done), ToDb(progress_total), id, worker_id);
    if (r.empty()) {
      CheckClaim(t, id, worker_id);  // Throws the reason.
      throw Abort{absl::FailedPreconditionError(absl::StrCat("job \"", id, "\" changed hands"))};
    }
    Notify(t, id);
    return r[0][0].as<bool>();
  });
}

absl::Status PostgresJobStore::Complete(const std::string& id, const std::string& worker_id,
                                        const Completion& completion, TimeMs now) {
  if (!IsTerminal(completion.state)) {
    return absl::InvalidArgumentError(absl::StrCat("cannot complete job \"", id, "\" as ",
                                                   StateName(completion.state),
                                                   ": not a terminal state"));
  }
  return InTxnVoid("complete a job", [&](pqxx::work& t) {
    CheckClaim(t, id, worker_id);
    // Empty completion warnings keep the ones recorded at submit time.
    t.exec_params(
        "UPDATE jobs SET state = $1, end_time = $2, error = $3, result_key = $4, "
        "result_size = $5, result_sha256 = $6, "
        "warnings = CASE WHEN $7 = '' THEN warnings ELSE $7 END, "
        "worker_id = '', lease_expiry = 0, error_code = $8 WHERE id = $9",
        static_cast<int>(completion.state), now, BoundText(completion.error, kMaxErrorBytes),
        completion.result_key, ToDb(completion.result_size), completion.result_sha256,
        BoundText(completion.warnings, kMaxWarningsBytes), completion.error_code, id);
    PropagateShardEnd(t, id, now);
    AppendEventIn(t, id, EndEvent(worker_id, completion, now));
    // Previews matter only while the job runs.
    t.exec_params("DELETE FROM previews WHERE job_id = $1", id);
    t.exec_params("DELETE FROM preview_wishes WHERE job_id = $1", id);
    Notify(t, id);
  });
}

absl::Status PostgresJobStore::AbandonAttempt(const std::string& id, const std::string& worker_id,
                                              const std::string& error, int error_code) {
  return GiveBack(id, worker_id, AttemptEnd{BoundText(error, kMaxErrorBytes), error_code});
}

absl::Status PostgresJobStore::Release(const std::string& id, const std::string& worker_id) {
  return GiveBack(id, worker_id, std::nullopt);
}

absl::Status PostgresJobStore::GiveBack(const std::string& id, const std::string& worker_id,
                                        const std::optional<AttemptEnd>& attempt) {
  return InTxnVoid("give a job back", [&](pqxx::work& t) {
    CheckClaim(t, id, worker_id);
    // As in the SQLite store: a cancel-requested job ends CANCELLED rather
    // than sitting QUEUED where nothing would ever claim it.
    t.exec_params(
        "UPDATE jobs SET worker_id = '', lease_expiry = 0, "
        "state = CASE WHEN cancel_requested THEN 5 ELSE 1 END, "
        "error = CASE WHEN cancel_requested THEN $1 WHEN $2 THEN $3 ELSE error END, "
        "error_code = CASE WHEN cancel_requested THEN $4 WHEN $2 THEN $5 ELSE error_code END "
        "WHERE id = $6",
        std::string(kCancelledByRequest), attempt.has_value(),
        attempt ? attempt->error : std::string(), kCancelledCode, attempt ? attempt->code : 0, id);
    PropagateShardEnd(t, id, WallClockMs());  // when it ended CANCELLED
    Notify(t, id, /*claimable=*/true);
  });
}

absl::StatusOr<JobRecord> PostgresJobStore::RequestCancel(const std::string& id, TimeMs now,
                                                          const std::string& by) {
  return InTxn<JobRecord>("cancel a job", [&](pqxx::work& t) {
    JobRecord job = LoadExisting(t, id, true);
    if (IsTerminal(job.state)) return job;
    pqxx::result r =
        job.state == JobState::kQueued
            ? t.exec_params("UPDATE jobs SET state = 5, end_time = $1, error = $2, "
                            "cancel_requested = TRUE, error_code = $3 WHERE id = $4 "
                            "RETURNING " NIMBUS_PG_COLUMNS,
                            now, std::string(kCancelledByRequest), kCancelledCode, id)
            : t.exec_params("UPDATE jobs SET cancel_requested = TRUE WHERE id = $1 "
                            "RETURNING " NIMBUS_PG_COLUMNS,
                            id);
    if (job.state == JobState::kQueued) AppendEventIn(t, id, QueuedCancelEvent(by, now));
    if (job.shard_count > 1 && job.parent_id.empty())
      StopShards(t, id, now, kCancelledByRequest);
    if (job.state == JobState::kQueued) PropagateShardEnd(t, id, now);  // a cancelled shard
    Notify(t, id);
    return RowToRecord(r[0]);
  });
}

absl::StatusOr<int> PostgresJobStore::RequeueRunning() {
  return InTxn<int>("requeue running jobs", [&](pqxx::work& t) {
    CancelOrphans(t, WallClockMs(), /*lapsed_only=*/false);
    for (const pqxx::row& held : t.exec("SELECT id, worker_id FROM jobs WHERE state = 2"))
      AppendEventIn(t, held[0].as<std::string>(),
                    {0,
                     WallClockMs(),
                     "lease_lost",
                     {{"worker", held[1].as<std::string>()}, {"reason", "restart"}}});
    pqxx::result r = t.exec(
        "UPDATE jobs SET state = 1, worker_id = '', lease_expiry = 0 WHERE state = 2");
    t.exec_params("SELECT pg_notify($1, 'q')", std::string(kChannel));
    return static_cast<int>(r.affected_rows());
  });
}

absl::StatusOr<OwnerUsage> PostgresJobStore::Usage(const std::string& owner) {
  return InTxn<OwnerUsage>("read usage", [&](pqxx::work& t) {
    pqxx::row r = t.exec_params1(
        "SELECT count(*) FILTER (WHERE state IN (1, 2)), "
        "coalesce(sum(result_size) FILTER (WHERE state = 3 AND result_expire_time = 0), 0) "
        "FROM jobs WHERE owner = $1 AND parent_id = ''",
        owner);
    OwnerUsage u;
    u.active_jobs = FromDb(r[0]);
    u.result_bytes = FromDb(r[1]);
    return u;
  });
}

absl::StatusOr<JobRecord> PostgresJobStore::SetPinned(const std::string& id, bool pinned) {
  return InTxn<JobRecord>("pin a job", [&](pqxx::work& t) {
    pqxx::result r = t.exec_params(
        "UPDATE jobs SET pinned = $1 WHERE id = $2 RETURNING " NIMBUS_PG_COLUMNS, pinned, id);
    if (r.empty())
      throw Abort{absl::NotFoundError(absl::StrCat("job \"", EchoId(id), "\" not found"))};
    return RowToRecord(r[0]);
  });
}

absl::Status PostgresJobStore::Delete(const std::string& id) {
  return InTxnVoid("delete a job", [&](pqxx::work& t) {
    JobRecord job = LoadExisting(t, id, true);
    if (!IsTerminal(job.state))
      throw Abort{absl::FailedPreconditionError(absl::StrCat(
          "job ", id, " is ", StateName(job.state), "; cancel it before deleting it"))};
    pqxx::result active = t.exec_params(
        "SELECT id FROM jobs WHERE parent_id = $1 AND state IN (1, 2) LIMIT 1 FOR UPDATE", id);
    if (!active.empty())
      throw Abort{absl::FailedPreconditionError(absl::StrCat(
          "job ", id, " still has an active shard (", active[0][0].as<std::string>(), ")"))};
    for (const char* sql :
         {"DELETE FROM pokes WHERE job_id IN (SELECT $1 UNION ALL "
          "SELECT id FROM jobs WHERE parent_id = $1)",
          "DELETE FROM previews WHERE job_id IN (SELECT $1 UNION ALL "
          "SELECT id FROM jobs WHERE parent_id = $1)",
          "DELETE FROM preview_wishes WHERE job_id IN (SELECT $1 UNION ALL "
          "SELECT id FROM jobs WHERE parent_id = $1)",
          "DELETE FROM job_events WHERE job_id = $1",
          "DELETE FROM jobs WHERE parent_id = $1 AND $1 <> ''", "DELETE FROM jobs WHERE id = $1"})
      t.exec_params(sql, id);
  });
}

absl::StatusOr<std::vector<JobRecord>> PostgresJobStore::ListExpiring(TimeMs cutoff, int limit) {
  return InTxn<std::vector<JobRecord>>("list expiring results", [&](pqxx::work& t) {
    pqxx::result rows = t.exec_params(
        "SELECT " NIMBUS_PG_COLUMNS
        " FROM jobs WHERE state = 3 AND NOT pinned AND result_expire_time = 0 AND "
        "parent_id = '' AND end_time < $1 ORDER BY end_time LIMIT $2",
        cutoff, limit);
    std::vector<JobRecord> jobs;
    for (const pqxx::row& row : rows) jobs.push_back(RowToRecord(row));
    return jobs;
  });
}

absl::Status PostgresJobStore::MarkResultExpired(const std::string& id, TimeMs now) {
  return InTxnVoid("mark a result expired", [&](pqxx::work& t) {
    t.exec_params("UPDATE jobs SET result_expire_time = $1 WHERE id = $2 AND state = 3", now, id);
  });
}

absl::StatusOr<std::vector<std::string>> PostgresJobStore::SpecsInUse() {
  return InTxn<std::vector<std::string>>("list specs in use", [&](pqxx::work& t) {
    pqxx::result rows =
        t.exec("SELECT encode(spec, 'hex') FROM jobs WHERE state IN (1, 2) OR pinned");
    std::vector<std::string> specs;
    for (const pqxx::row& row : rows) specs.push_back(HexToBytes(row[0].as<std::string>()));
    return specs;
  });
}

absl::StatusOr<PokeRecord> PostgresJobStore::AddPoke(const std::string& id,
                                                     const PokeRecord& poke) {
  return InTxn<PokeRecord>("add a poke", [&](pqxx::work& t) {
    JobRecord job = LoadExisting(t, id, true);
    if (job.state != JobState::kRunning)
      throw Abort{absl::FailedPreconditionError(absl::StrCat(
          "job ", EchoId(id), " is ", StateName(job.state), "; pokes act on RUNNING jobs only"))};
    pqxx::row r = t.exec_params1(
        "INSERT INTO pokes (job_id, frame, body, drag, x, y, z, drag_stiffness, drag_frames) "
        "VALUES ($1, -1, $2, $3, $4, $5, $6, $7, $8) RETURNING seq",
        id, poke.body, poke.drag, poke.x, poke.y, poke.z, poke.drag_stiffness,
        int64_t{poke.drag_frames});
    PokeRecord out = poke;
    out.seq = r[0].as<int64_t>();
    out.frame = -1;
    return out;
  });
}

absl::StatusOr<std::vector<PokeRecord>> PostgresJobStore::TakePokes(const std::string& id,
                                                                    const std::string& worker_id,
                                                                    int64_t frame) {
  return InTxn<std::vector<PokeRecord>>("take pokes", [&](pqxx::work& t) {
    CheckClaim(t, id, worker_id);
    t.exec_params("UPDATE pokes SET frame = $2 WHERE job_id = $1 AND frame < 0", id, frame);
    pqxx::result rows = t.exec_params(
        "SELECT seq, frame, body, drag, x, y, z, drag_stiffness, drag_frames FROM pokes "
        "WHERE job_id = $1 AND frame = $2 ORDER BY seq",
        id, frame);
    std::vector<PokeRecord> out;
    for (const pqxx::row& r : rows) {
      out.push_back({r[0].as<int64_t>(), r[1].as<int64_t>(), r[2].as<int32_t>(), r[3].as<bool>(),
                     r[4].as<double>(), r[5].as<double>(), r[6].as<double>(), r[7].as<double>(),
                     static_cast<uint32_t>(r[8].as<int64_t>())});
    }
    return out;
  });
}

absl::Status PostgresJobStore::WishPreviews(const std::string& id,
                                            const std::vector<PreviewWish>& wishes, TimeMs until) {
  return InTxnVoid("record preview wishes", [&](pqxx::work& t) {
    for (const PreviewWish& w : wishes) {
      t.exec_params(
          "INSERT INTO preview_wishes (job_id, resolution, interval_ms, until) "
          "VALUES ($1, $2, $3, $4) ON CONFLICT (job_id, resolution) DO UPDATE SET "
          "interval_ms = excluded.interval_ms, until = excluded.until",
          id, int64_t{w.resolution}, int64_t(w.interval_seconds * 1000), until);
    }
  });
}

absl::StatusOr<std::vector<PreviewWish>> PostgresJobStore::PreviewWishes(const std::string& id,
                                                                         TimeMs now) {
  return InTxn<std::vector<PreviewWish>>("read preview wishes", [&](pqxx::work& t) {
    pqxx::result rows = t.exec_params(
        "SELECT resolution, interval_ms FROM preview_wishes WHERE job_id = $1 AND until >= $2 "
        "ORDER BY resolution",
        id, now);
    std::vector<PreviewWish> out;
    for (const pqxx::row& r : rows)
      out.push_back({static_cast<uint32_t>(r[0].as<int64_t>()), r[1].as<int64_t>() / 1000.0});
    return out;
  });
}

absl::Status PostgresJobStore::PutPreview(const std::string& id, uint32_t resolution,
                                          uint64_t sequence, const std::string& preview) {
  return InTxnVoid("store a preview", [&](pqxx::work& t) {
    t.exec_params(
        "INSERT INTO previews (job_id, resolution, sequence, data) "
        "VALUES ($1, $2, $3, decode($4, 'hex')) ON CONFLICT (job_id, resolution) DO UPDATE SET "
        "sequence = excluded.sequence, data = excluded.data "
        "WHERE previews.sequence < excluded.sequence",
        id, int64_t{resolution}, ToDb(sequence), absl::BytesToHexString(preview));
    t.exec_params("SELECT pg_notify($1, $2)", std::string(kChannel), absl::StrCat("p ", id));
  });
}

absl::StatusOr<std::string> PostgresJobStore::LatestPreview(const std::string& id,
                                                            uint32_t resolution) {
  return InTxn<std::string>("read a preview", [&](pqxx::work& t) {
    pqxx::result r = t.exec_params(
        "SELECT encode(data, 'hex') FROM previews WHERE job_id = $1 AND resolution = $2", id,
        int64_t{resolution});
    if (r.empty())
      throw Abort{absl::NotFoundError(absl::StrCat("no stored preview of job ", EchoId(id)))};
    return HexToBytes(r[0][0].as<std::string>());
  });
}

void PostgresJobStore::StopShards(pqxx::work& t, const std::string& parent_id, TimeMs now,
                                  const std::string& error) {
  t.exec_params(
      "UPDATE jobs SET state = 5, end_time = $2, error = $3, error_code = $4, "
      "cancel_requested = TRUE WHERE parent_id = $1 AND state = 1",
      parent_id, now, error, kCancelledCode);
  t.exec_params("UPDATE jobs SET cancel_requested = TRUE WHERE parent_id = $1 AND state = 2",
                parent_id);
}

void PostgresJobStore::PropagateShardEnd(pqxx::work& t, const std::string& id, TimeMs now) {
  pqxx::result r = t.exec_params(
      "SELECT parent_id, shard_index, shard_count, state, error, error_code FROM jobs "
      "WHERE id = $1",
      id);
  if (r.empty() || r[0][0].as<std::string>().empty()) return;
  const std::string parent = r[0][0].as<std::string>();
  const auto state = static_cast<JobState>(r[0][3].as<int>());
  if (!IsTerminal(state)) return;
  if (state == JobState::kSucceeded) {
    // Row-locked by the UPDATE: concurrent shard ends count down one by one,
    // and exactly one of them sees zero.
    pqxx::result left = t.exec_params(
        "UPDATE jobs SET shards_pending = shards_pending - 1 WHERE id = $1 AND "
        "shards_pending > 0 RETURNING shards_pending",
        parent);
    if (!left.empty() && left[0][0].as<int64_t>() == 0) Notify(t, parent, /*claimable=*/true);
    return;
  }
  // FAILED or CANCELLED: the parent ends too, unless it already has.
  const std::string why = absl::StrCat("shard ", r[0][1].as<int64_t>(), " of ",
                                       r[0][2].as<int64_t>(), ": ", r[0][4].as<std::string>());
  const int code = state == JobState::kCancelled && r[0][5].as<int>() == 0
                       ? kCancelledCode
                       : r[0][5].as<int>();
  pqxx::result ended = t.exec_params(
      "UPDATE jobs SET state = $2, end_time = $3, error = $4, error_code = $5, "
      "worker_id = '', lease_expiry = 0 WHERE id = $1 AND state IN (1, 2) RETURNING id",
      parent, static_cast<int>(state), now, BoundText(why, kMaxErrorBytes), code);
  if (ended.empty()) return;
  StopShards(t, parent, now, BoundText(why, kMaxErrorBytes));
  Notify(t, parent);
}

absl::StatusOr<std::vector<JobRecord>> PostgresJobStore::ListShards(
    const std::string& parent_id) {
  return InTxn<std::vector<JobRecord>>("list shards", [&](pqxx::work& t) {
    LoadExisting(t, parent_id, false);  // NOT_FOUND for an unknown id
    pqxx::result rows = t.exec_params("SELECT " NIMBUS_PG_COLUMNS
                                      " FROM jobs WHERE parent_id = $1 ORDER BY shard_index",
                                      parent_id);
    std::vector<JobRecord> shards;
    for (const pqxx::row& row : rows) shards.push_back(RowToRecord(row));
    return shards;
  });
}

absl::StatusOr<std::optional<JobRecord>> PostgresJobStore::FindCached(
    const std::string& spec_sha256, const std::string& owner) {
  if (spec_sha256.empty()) return std::optional<JobRecord>();
  return InTxn<std::optional<JobRecord>>("look up the result cache", [&](pqxx::work& t) {
    pqxx::result r = t.exec_params(
        "SELECT " NIMBUS_PG_COLUMNS
        " FROM jobs WHERE spec_sha256 = $1 AND owner = $2 AND state = 3 AND "
        "result_expire_time = 0 AND parent_id = '' ORDER BY end_time DESC, id DESC LIMIT 1",
        spec_sha256, owner);
    if (r.empty()) return std::optional<JobRecord>();
    return std::optional<JobRecord>(RowToRecord(r[0]));
  });
}

extern "C" NIMBUS_POSTGRES_EXPORT void NimbusOpenPostgresJobStore(
    const std::string& url, absl::StatusOr<std::unique_ptr<JobStore>>& out) {
  out = PostgresJobStore::Open(url);
}

#undef NIMBUS_PG_COLUMNS

}  // namespace nimbus::server
