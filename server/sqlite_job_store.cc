// SQLite implementation of JobStore: a writing connection guarded by a
// mutex, WAL mode, and BEGIN IMMEDIATE around every read-modify-write so that
// several processes sharing the file (e.g. two replicas on one volume) still
// see claims as atomic. Plain reads (Get, List) use a second, read-only
// connection with its own mutex: in WAL mode readers never wait for the
// write lock, so a write stuck behind another process's transaction does
// not hold up every status query, and each read still sees every commit
// that finished before it started.
#include <sqlite3.h>

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <functional>
#include <limits>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/escaping.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "server/bounded_text.h"
#include "server/job_store.h"
#include "server/job_store_util.h"
#include "server/sqlite_claim_sql.h"

namespace nimbus::server {
namespace {

// 1: the first schema. 2: adds jobs.error_code. 3: adds owner, pinned and
// result_expire_time (security: ownership and retention). 4: adds the pokes
// table (jelly jobs). 5: adds sharded jobs (parent_id, shard_index,
// shard_count, shards_pending) and the result cache (spec_sha256,
// cached_from). 6: idempotency keys per principal. 7: priorities, retries
// and the fair-share claim order (owner_claims).
constexpr int kSchemaVersion = 7;
// Long enough to ride out another process's short write transactions, short
// enough that a wedged peer surfaces as UNAVAILABLE instead of a hang.
constexpr int kBusyTimeoutMs = 10000;
constexpr int kDefaultPageSize = 50;
constexpr int kMaxPageSize = 500;
constexpr char kCancelledByRequest[] = "cancelled by request";
constexpr int kCancelledCode = static_cast<int>(absl::StatusCode::kCancelled);

// Pokes on running jelly jobs; frame -1 until the job's runner takes them.
#define NIMBUS_POKES_SQL                                                                \
  "CREATE TABLE IF NOT EXISTS pokes (seq INTEGER PRIMARY KEY, job_id TEXT NOT NULL, "    \
  "frame INTEGER NOT NULL DEFAULT -1, body INTEGER NOT NULL, drag INTEGER NOT NULL, "     \
  "x REAL NOT NULL, y REAL NOT NULL, z REAL NOT NULL, drag_stiffness REAL NOT NULL, "    \
  "drag_frames INTEGER NOT NULL);"                                                      \
  "CREATE INDEX IF NOT EXISTS pokes_job_frame ON pokes (job_id, frame, seq);"

constexpr char kSchemaSql[] = R"sql(
CREATE TABLE IF NOT EXISTS jobs (
  id TEXT PRIMARY KEY NOT NULL,
  name TEXT NOT NULL DEFAULT '',
  state INTEGER NOT NULL,
  spec BLOB NOT NULL,
  request_id TEXT NOT NULL DEFAULT '',
  create_time INTEGER NOT NULL,
  start_time INTEGER NOT NULL DEFAULT 0,
  end_time INTEGER NOT NULL DEFAULT 0,
  attempts INTEGER NOT NULL DEFAULT 0,
  cancel_requested INTEGER NOT NULL DEFAULT 0,
  worker_id TEXT NOT NULL DEFAULT '',
  lease_expiry INTEGER NOT NULL DEFAULT 0,
  progress_done INTEGER NOT NULL DEFAULT 0,
  progress_total INTEGER NOT NULL DEFAULT 0,
  error TEXT NOT NULL DEFAULT '',
  result_key TEXT NOT NULL DEFAULT '',
  result_size INTEGER NOT NULL DEFAULT 0,
  result_sha256 TEXT NOT NULL DEFAULT '',
  warnings TEXT NOT NULL DEFAULT '',
  estimated_memory_bytes INTEGER NOT NULL DEFAULT 0,
  error_code INTEGER NOT NULL DEFAULT 0,
  owner TEXT NOT NULL DEFAULT '',
  pinned INTEGER NOT NULL DEFAULT 0,
  result_expire_time INTEGER NOT NULL DEFAULT 0
);
-- A principal's own listing, newest first.
CREATE INDEX IF NOT EXISTS jobs_owner_create ON jobs (owner, create_time, id);
-- Claiming (oldest QUEUED) and filtered listing both walk this index.
CREATE INDEX IF NOT EXISTS jobs_state_create ON jobs (state, create_time, id);
-- Unfiltered listing, newest first.
CREATE INDEX IF NOT EXISTS jobs_create ON jobs (create_time, id);
-- Idempotency keys are unique, but most jobs have none.
CREATE UNIQUE INDEX IF NOT EXISTS jobs_request_id ON jobs (request_id) WHERE request_id <> '';
)sql" NIMBUS_POKES_SQL;

// Version 1 files gain the status code of failed and cancelled jobs. Jobs
// that ended before codes were kept get CANCELLED (1) or UNKNOWN (2).
constexpr char kMigrateToV2Sql[] = R"sql(
ALTER TABLE jobs ADD COLUMN error_code INTEGER NOT NULL DEFAULT 0;
UPDATE jobs SET error_code = 1 WHERE state = 5;
UPDATE jobs SET error_code = 2 WHERE state = 4;
)sql";

// Version 2 files gain owners (older jobs get none: only admins see them),
// pins and the time a result expired.
constexpr char kMigrateToV3Sql[] = R"sql(
ALTER TABLE jobs ADD COLUMN owner TEXT NOT NULL DEFAULT '';
ALTER TABLE jobs ADD COLUMN pinned INTEGER NOT NULL DEFAULT 0;
ALTER TABLE jobs ADD COLUMN result_expire_time INTEGER NOT NULL DEFAULT 0;
CREATE INDEX IF NOT EXISTS jobs_owner_create ON jobs (owner, create_time, id);
)sql";

// Version 3 files gain the pokes table (no job has pokes yet).
constexpr char kMigrateToV4Sql[] = NIMBUS_POKES_SQL;

// Version 4 files gain shards and the result cache; a fresh file gets
// these columns on top of kSchemaSql too.
constexpr char kMigrateToV5Sql[] = R"sql(
ALTER TABLE jobs ADD COLUMN parent_id TEXT NOT NULL DEFAULT '';
ALTER TABLE jobs ADD COLUMN shard_index INTEGER NOT NULL DEFAULT 0;
ALTER TABLE jobs ADD COLUMN shard_count INTEGER NOT NULL DEFAULT 0;
ALTER TABLE jobs ADD COLUMN shards_pending INTEGER NOT NULL DEFAULT 0;
ALTER TABLE jobs ADD COLUMN spec_sha256 TEXT NOT NULL DEFAULT '';
ALTER TABLE jobs ADD COLUMN cached_from TEXT NOT NULL DEFAULT '';
CREATE INDEX IF NOT EXISTS jobs_parent ON jobs (parent_id, shard_index) WHERE parent_id <> '';
CREATE INDEX IF NOT EXISTS jobs_spec_sha256 ON jobs (spec_sha256, owner)
  WHERE spec_sha256 <> '';
)sql";

// Version 5 files key idempotent submissions by principal: the same
// request_id from two principals is two jobs, and neither learns of the
// other. Every file runs it, a fresh one too.
constexpr char kMigrateToV6Sql[] = R"sql(
DROP INDEX IF EXISTS jobs_request_id;
CREATE UNIQUE INDEX IF NOT EXISTS jobs_owner_request_id ON jobs (owner, request_id)
  WHERE request_id <> '';
)sql";

// Version 6 files gain priorities (old jobs get the default, 50), the link
// from a retry to its original, and what the claim order reads: an index of
// claimable QUEUED jobs by (priority, owner, age), RUNNING jobs by owner,
// and each owner's last claim (a counter, so equal clocks still order);
// the worker registry and the job event log. Every file runs it, a fresh
// one too.
constexpr char kMigrateToV7Sql[] = R"sql(
ALTER TABLE jobs ADD COLUMN priority INTEGER NOT NULL DEFAULT 50;
ALTER TABLE jobs ADD COLUMN retried_from TEXT NOT NULL DEFAULT '';
CREATE INDEX IF NOT EXISTS jobs_claim_order ON jobs (priority, owner, create_time)
  WHERE state = 1 AND cancel_requested = 0 AND shards_pending = 0;
CREATE INDEX IF NOT EXISTS jobs_state_owner ON jobs (state, owner);
CREATE TABLE IF NOT EXISTS owner_claims (owner TEXT PRIMARY KEY NOT NULL,
  last_claim INTEGER NOT NULL);
CREATE INDEX IF NOT EXISTS owner_claims_last ON owner_claims (last_claim);
CREATE TABLE IF NOT EXISTS workers (replica_id TEXT PRIMARY KEY NOT NULL,
  host TEXT NOT NULL, version TEXT NOT NULL, start_time INTEGER NOT NULL,
  worker_slots INTEGER NOT NULL, threads_per_job INTEGER NOT NULL,
  jobs_running INTEGER NOT NULL, last_heartbeat INTEGER NOT NULL);
CREATE TABLE IF NOT EXISTS job_events (job_id TEXT NOT NULL, seq INTEGER NOT NULL,
  time INTEGER NOT NULL, kind TEXT NOT NULL, fields TEXT NOT NULL,
  PRIMARY KEY (job_id, seq));
)sql";

// Column order shared by every SELECT that feeds RowToRecord. Text a client
// or a reader could make huge is cut in SQL already (stores written before
// the bounds may hold a gigabyte of error text), and again by BoundText
// wherever it is shown.
#define NIMBUS_JOB_COLUMNS                                                                 \
  "id, substr(name, 1, 256), state, spec, request_id, create_time, start_time, end_time, " \
  "attempts, cancel_requested, worker_id, lease_expiry, progress_done, progress_total, "   \
  "substr(error, 1, 4200), result_key, result_size, result_sha256, "                       \
  "substr(warnings, 1, 16500), estimated_memory_bytes, error_code, owner, pinned, "        \
  "result_expire_time, parent_id, shard_index, shard_count, shards_pending, spec_sha256, " \
  "cached_from, priority, retried_from"

absl::StatusCode CodeFor(int rc) {
  switch (rc & 0xff) {
    case SQLITE_BUSY:
    case SQLITE_LOCKED:
      return absl::StatusCode::kUnavailable;  // Retryable contention.
    case SQLITE_CONSTRAINT:
      return absl::StatusCode::kAlreadyExists;
    case SQLITE_FULL:
      return absl::StatusCode::kResourceExhausted;
    case SQLITE_READONLY:
    case SQLITE_PERM:
      return absl::StatusCode::kPermissionDenied;
    default:
      return absl::StatusCode::kInternal;
  }
}

std::string DbPath(sqlite3* db) {
  const char* name = db == nullptr ? nullptr : sqlite3_db_filename(db, "main");
  return name == nullptr ? std::string("?") : std::string(name);
}

// Names the failing step, the database file, and SQLite's own explanation.
absl::Status SqliteError(sqlite3* db, int rc, const std::string& what) {
  const char* msg = db != nullptr ? sqlite3_errmsg(db) : sqlite3_errstr(rc);
  return absl::Status(CodeFor(rc),
                      absl::StrCat("job store ", DbPath(db), ": ", what, ": ",
                                   msg == nullptr ? "" : msg, " (sqlite code ", rc, ")"));
}

std::string StateName(JobState s) {
  switch (s) {
    case JobState::kQueued:
      return "QUEUED";
    case JobState::kRunning:
      return "RUNNING";
    case JobState::kSucceeded:
      return "SUCCEEDED";
    case JobState::kFailed:
      return "FAILED";
    case JobState::kCancelled:
      return "CANCELLED";
  }
  return absl::StrCat("state ", static_cast<int>(s));
}

// A cached prepared statement for the span of one use: bind, step, and on
// destruction reset so the next user starts clean and read locks are dropped.
class Statement {
 public:
  // `what` (the SQL text, for error messages) must outlive the statement.
  Statement(sqlite3_stmt* stmt, const std::string* what) : stmt_(stmt), what_(what) {}
  ~Statement() {
    sqlite3_reset(stmt_);
    sqlite3_clear_bindings(stmt_);
  }
  Statement(const Statement&) = delete;
  Statement& operator=(const Statement&) = delete;

  Statement& Bind(int index, int64_t v) { return Check(sqlite3_bind_int64(stmt_, index, v)); }
  Statement& Bind(int index, uint64_t v) {
    // Stored as the same 64 bits; read back with the inverse cast.
    return Bind(index, static_cast<int64_t>(v));
  }
  Statement& Bind(int index, int v) { return Bind(index, static_cast<int64_t>(v)); }
  Statement& Bind(int index, JobState v) { return Bind(index, static_cast<int64_t>(v)); }
  Statement& BindDouble(int index, double v) { return Check(sqlite3_bind_double(stmt_, index, v)); }
  Statement& Bind(int index, const std::string& v) {
    return Check(
        sqlite3_bind_text(stmt_, index, v.data(), static_cast<int>(v.size()), SQLITE_TRANSIENT));
  }
  Statement& BindBlob(int index, const std::string& v) {
    // zeroblob keeps an empty spec a zero-length BLOB rather than NULL.
    if (v.empty()) return Check(sqlite3_bind_zeroblob(stmt_, index, 0));
    return Check(
        sqlite3_bind_blob(stmt_, index, v.data(), static_cast<int>(v.size()), SQLITE_TRANSIENT));
  }

  /// Ready to run again with new bindings.
  void Reset() {
    sqlite3_reset(stmt_);
    sqlite3_clear_bindings(stmt_);
    bind_rc_ = SQLITE_OK;
  }

  /// True when a row is available, false when done.
  absl::StatusOr<bool> Step() {
    if (bind_rc_ != SQLITE_OK) return Error(bind_rc_);
    const int rc = sqlite3_step(stmt_);
    if (rc == SQLITE_ROW) return true;
    if (rc == SQLITE_DONE) return false;
    return Error(rc);
  }
  /// Runs a statement that returns no rows.
  absl::Status Run() {
    absl::StatusOr<bool> r = Step();
    return r.ok() ? absl::OkStatus() : r.status();
  }

  int64_t Int(int col) const { return sqlite3_column_int64(stmt_, col); }
  uint64_t Uint(int col) const { return static_cast<uint64_t>(Int(col)); }
  double Double(int col) const { return sqlite3_column_double(stmt_, col); }
  std::string Text(int col) const {
    const auto* p = reinterpret_cast<const char*>(sqlite3_column_text(stmt_, col));
    return p == nullptr ? std::string() : std::string(p, sqlite3_column_bytes(stmt_, col));
  }
  std::string Blob(int col) const {
    const auto* p = static_cast<const char*>(sqlite3_column_blob(stmt_, col));
    return p == nullptr ? std::string() : std::string(p, sqlite3_column_bytes(stmt_, col));
  }

 private:
  Statement& Check(int rc) {
    if (rc != SQLITE_OK && bind_rc_ == SQLITE_OK) bind_rc_ = rc;
    return *this;
  }
  absl::Status Error(int rc) const { return SqliteError(sqlite3_db_handle(stmt_), rc, *what_); }

  sqlite3_stmt* stmt_;
  const std::string* what_;
  int bind_rc_ = SQLITE_OK;
};

JobRecord RowToRecord(const Statement& s) {
  JobRecord r;
  r.id = s.Text(0);
  r.name = s.Text(1);
  r.state = static_cast<JobState>(s.Int(2));
  r.spec = s.Blob(3);
  r.request_id = s.Text(4);
  r.create_time = s.Int(5);
  r.start_time = s.Int(6);
  r.end_time = s.Int(7);
  r.attempts = static_cast<uint32_t>(s.Int(8));
  r.cancel_requested = s.Int(9) != 0;
  r.worker_id = s.Text(10);
  r.lease_expiry = s.Int(11);
  r.progress_done = s.Uint(12);
  r.progress_total = s.Uint(13);
  r.error = s.Text(14);
  r.result_key = s.Text(15);
  r.result_size = s.Uint(16);
  r.result_sha256 = s.Text(17);
  r.warnings = s.Text(18);
  r.estimated_memory_bytes = s.Uint(19);
  r.error_code = static_cast<int>(s.Int(20));
  r.owner = s.Text(21);
  r.pinned = s.Int(22) != 0;
  r.result_expire_time = s.Int(23);
  r.parent_id = s.Text(24);
  r.shard_index = static_cast<uint32_t>(s.Int(25));
  r.shard_count = static_cast<uint32_t>(s.Int(26));
  r.shards_pending = static_cast<uint32_t>(s.Int(27));
  r.spec_sha256 = s.Text(28);
  r.cached_from = s.Text(29);
  r.priority = static_cast<int>(s.Int(30));
  r.retried_from = s.Text(31);
  return r;
}


}  // namespace

class SqliteJobStore final : public JobStore {
 public:
  static absl::StatusOr<std::unique_ptr<JobStore>> Open(const std::string& path);
  ~SqliteJobStore() override;
  SqliteJobStore(const SqliteJobStore&) = delete;
  SqliteJobStore& operator=(const SqliteJobStore&) = delete;

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

 private:
  // How an attempt ended, kept when the job goes back to the queue.
  struct AttemptEnd {
    std::string error;
    int code = 0;
  };
  // Release and AbandonAttempt: the claimed job back to QUEUED (or
  // CANCELLED when a cancel is pending), with `attempt`'s error if given.
  absl::Status GiveBack(const std::string& id, const std::string& worker_id,
                        const std::optional<AttemptEnd>& attempt);

 public:
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
  // Appends to `job_id`'s event log inside the caller's transaction.
  absl::Status AppendEventLocked(const std::string& job_id, const JobEvent& event);
  // Runs one write statement binding `bind`; the rows it changed.
  absl::StatusOr<int> RunWrite(const char* sql, const std::function<void(Statement&)>& bind);

  // Rolls back unless committed, so every early return leaves no open
  // transaction (and no held write lock) behind.
  class Transaction {
   public:
    explicit Transaction(SqliteJobStore* store) : store_(store) {}
    ~Transaction() {
      if (open_) sqlite3_exec(store_->w_.db, "ROLLBACK", nullptr, nullptr, nullptr);
    }
    absl::Status Begin() {
      // IMMEDIATE takes the write lock up front: a deferred transaction that
      // upgrades from read to write can fail with SQLITE_BUSY in WAL mode
      // without the busy handler ever waiting.
      absl::Status s = store_->Exec("BEGIN IMMEDIATE");
      open_ = s.ok();
      return s;
    }
    absl::Status Commit() {
      absl::Status s = store_->Exec("COMMIT");
      if (s.ok()) open_ = false;
      return s;
    }

   private:
    SqliteJobStore* store_;
    bool open_ = false;
  };

  // One SQLite connection and its prepared statements, keyed by SQL text
  // (prepared once, reused for the connection's lifetime).
  struct Connection {
    sqlite3* db = nullptr;
    std::unordered_map<std::string, sqlite3_stmt*> stmts;
    absl::StatusOr<Statement> Prepare(const char* sql);
    void Close();
  };

  explicit SqliteJobStore(sqlite3* db) { w_.db = db; }

  absl::Status Init();
  absl::Status Migrate();
  // Opens the read connection, or shares the writer's for ":memory:".
  absl::Status OpenReader(const std::string& path);
  absl::Status Exec(const char* sql);
  absl::StatusOr<Statement> Prepare(const char* sql) { return w_.Prepare(sql); }
  absl::StatusOr<std::optional<JobRecord>> LoadLocked(Connection& c, const std::string& id);
  absl::StatusOr<JobRecord> LoadExistingLocked(Connection& c, const std::string& id);
  absl::StatusOr<JobRecord> LoadExistingLocked(const std::string& id) {
    return LoadExistingLocked(w_, id);
  }
  // OK when `worker_id` holds a live claim on `id`; FAILED_PRECONDITION (or
  // NOT_FOUND) otherwise.
  absl::Status CheckClaimLocked(const std::string& id, const std::string& worker_id);
  // A cancel-requested RUNNING job whose worker is gone (lease lapsed or
  // process restarted) can never be finished by that worker; finish it here.
  absl::Status CancelOrphansLocked(const char* where_clause_sql, TimeMs now);
  // The (create_time, id) of the next job by the claim order, if any.
  absl::StatusOr<std::optional<std::pair<TimeMs, std::string>>> PickClaimableLocked(TimeMs now);
  // Fair share among the owners of claimable QUEUED jobs at `priority`:
  // the winner's oldest job.
  absl::StatusOr<std::optional<OwnerTurn>> NextOwnerTurnLocked(int64_t priority);
  // Records that the owner of `id` was served now (owner_claims).
  absl::Status NoteClaimLocked(const std::string& id);
  // Fails a job whose attempts ran out, keeping its last attempt's error.
  absl::Status GiveUpLocked(const std::string& id, uint32_t attempts, TimeMs now);
  // Sharded jobs (docs/sharding.md). After `id` reached a terminal state: a
  // shard that SUCCEEDED counts down its parent's shards_pending; one that
  // FAILED or was CANCELLED ends its parent the same way (and its siblings).
  absl::Status ShardEndedLocked(const std::string& id, TimeMs now);
  // QUEUED shards of `parent_id` become CANCELLED, RUNNING ones get
  // cancel_requested.
  absl::Status CancelShardsLocked(const std::string& parent_id, TimeMs now);
  absl::Status InsertShardsLocked(const NewJob& job, TimeMs now);

  std::mutex mu_;  // guards w_
  Connection w_;
  // The read connection and its lock; the writer's own when not separate.
  std::mutex own_read_mu_;
  Connection own_reader_;
  std::mutex* read_mu_ = &mu_;
  Connection* r_ = &w_;
};

absl::StatusOr<std::unique_ptr<JobStore>> SqliteJobStore::Open(const std::string& path) {
  sqlite3* db = nullptr;
  // NOMUTEX: our own mutex serialises use of the connection.
  const int rc = sqlite3_open_v2(
      path.c_str(), &db, SQLITE_OPEN_READWRITE | SQLITE_OPEN_CREATE | SQLITE_OPEN_NOMUTEX, nullptr);
  if (rc != SQLITE_OK) {
    const std::string msg = db != nullptr ? sqlite3_errmsg(db) : sqlite3_errstr(rc);
    sqlite3_close(db);
    return absl::Status(CodeFor(rc), absl::StrCat("job store ", path, ": cannot open: ", msg,
                                                  " (sqlite code ", rc, ")"));
  }
  std::unique_ptr<SqliteJobStore> store(new SqliteJobStore(db));
  if (absl::Status s = store->Init(); !s.ok()) return s;
  if (absl::Status s = store->OpenReader(path); !s.ok()) return s;
  return std::unique_ptr<JobStore>(std::move(store));
}

void SqliteJobStore::Connection::Close() {
  for (auto& [sql, stmt] : stmts) sqlite3_finalize(stmt);
  stmts.clear();
  sqlite3_close_v2(db);
  db = nullptr;
}

SqliteJobStore::~SqliteJobStore() {
  if (r_ != &w_) own_reader_.Close();
  // The last connection: closing checkpoints the WAL into jobs.db and
  // removes it, so a clean stop leaves every job in the one file.
  w_.Close();
}

absl::Status SqliteJobStore::OpenReader(const std::string& path) {
  absl::StatusOr<Statement> mode = Prepare("PRAGMA journal_mode");
  if (!mode.ok()) return mode.status();
  absl::StatusOr<bool> row = mode->Step();
  if (!row.ok()) return row.status();
  // A ":memory:" database exists only in its own connection.
  if (!*row || mode->Text(0) != "wal") return absl::OkStatus();
  sqlite3* db = nullptr;
  const int rc = sqlite3_open_v2(path.c_str(), &db, SQLITE_OPEN_READONLY | SQLITE_OPEN_NOMUTEX,
                                 nullptr);
  if (rc != SQLITE_OK) {
    absl::Status s = SqliteError(db, rc, "open the read connection");
    sqlite3_close(db);
    return s;
  }
  sqlite3_extended_result_codes(db, 1);
  // Readers wait only in rare moments (e.g. WAL recovery after a crash).
  sqlite3_busy_timeout(db, kBusyTimeoutMs);
  own_reader_.db = db;
  r_ = &own_reader_;
  read_mu_ = &own_read_mu_;
  return absl::OkStatus();
}

absl::Status SqliteJobStore::Init() {
  sqlite3_extended_result_codes(w_.db, 1);
  // Before anything that may contend with another process opening the file.
  sqlite3_busy_timeout(w_.db, kBusyTimeoutMs);

  {
    absl::StatusOr<Statement> mode = Prepare("PRAGMA journal_mode=WAL");
    if (!mode.ok()) return mode.status();
    absl::StatusOr<bool> row = mode->Step();
    if (!row.ok()) return row.status();
    const std::string got = *row ? mode->Text(0) : std::string();
    // ":memory:" databases report "memory" and cannot use WAL; that is fine
    // for them since they are not shared or durable anyway.
    if (got != "wal" && got != "memory") {
      return absl::FailedPreconditionError(absl::StrCat(
          "job store ", DbPath(w_.db), ": cannot enable WAL journal mode (got \"", got, "\")"));
    }
  }
  // Durability: in WAL mode a commit appends to the -wal file with write();
  // NORMAL skips the fsync on each commit and syncs only at checkpoints. Once
  // write() returns the data is in the OS page cache, so it survives kill -9
  // (or any crash) of this process; only an OS crash or power loss can roll
  // back the last few commits, and even then the database stays consistent.
  // That is the trade we want: acceptance stays cheap and process crashes,
  // the failure we actually recover from, lose nothing.
  if (absl::Status s = Exec("PRAGMA synchronous=NORMAL"); !s.ok()) return s;
  return Migrate();
}

absl::Status SqliteJobStore::Migrate() {
  auto read_version = [this]() -> absl::StatusOr<int> {
    absl::StatusOr<Statement> v = Prepare("PRAGMA user_version");
    if (!v.ok()) return v.status();
    absl::StatusOr<bool> row = v->Step();
    if (!row.ok()) return row.status();
    const int version = *row ? static_cast<int>(v->Int(0)) : 0;
    if (version > kSchemaVersion) {
      return absl::FailedPreconditionError(
          absl::StrCat("job store ", DbPath(w_.db), ": schema version ", version,
                       " is newer than this binary supports (", kSchemaVersion, ")"));
    }
    return version;
  };
  absl::StatusOr<int> version = read_version();
  if (!version.ok() || *version == kSchemaVersion) return version.status();

  // Under the write lock so two processes opening the file at once do not
  // race; the version is read again inside, since the other may have won.
  Transaction txn(this);
  if (absl::Status s = txn.Begin(); !s.ok()) return s;
  version = read_version();
  if (!version.ok() || *version == kSchemaVersion) return version.status();
  // A fresh file gets the newest schema; older ones step up one version
  // at a time.
  if (*version == 0) {
    if (absl::Status s = Exec(kSchemaSql); !s.ok()) return s;
  } else {
    if (*version < 2)
      if (absl::Status s = Exec(kMigrateToV2Sql); !s.ok()) return s;
    if (*version < 3)
      if (absl::Status s = Exec(kMigrateToV3Sql); !s.ok()) return s;
    if (*version < 4)
      if (absl::Status s = Exec(kMigrateToV4Sql); !s.ok()) return s;
  }
  if (*version < 5)
    if (absl::Status s = Exec(kMigrateToV5Sql); !s.ok()) return s;
  if (*version < 6)
    if (absl::Status s = Exec(kMigrateToV6Sql); !s.ok()) return s;
  if (absl::Status s = Exec(kMigrateToV7Sql); !s.ok()) return s;
  if (absl::Status s = Exec(absl::StrCat("PRAGMA user_version=", kSchemaVersion).c_str());
      !s.ok()) {
    return s;
  }
  return txn.Commit();
}

absl::Status SqliteJobStore::Exec(const char* sql) {
  char* err = nullptr;
  const int rc = sqlite3_exec(w_.db, sql, nullptr, nullptr, &err);
  sqlite3_free(err);  // sqlite3_errmsg still holds the same text.
  if (rc != SQLITE_OK) return SqliteError(w_.db, rc, sql);
  return absl::OkStatus();
}

absl::StatusOr<Statement> SqliteJobStore::Connection::Prepare(const char* sql) {
  auto it = stmts.find(sql);
  if (it == stmts.end()) {
    sqlite3_stmt* stmt = nullptr;
    const int rc = sqlite3_prepare_v3(db, sql, -1, SQLITE_PREPARE_PERSISTENT, &stmt, nullptr);
    if (rc != SQLITE_OK) {
      sqlite3_finalize(stmt);
      return SqliteError(db, rc, absl::StrCat("prepare ", sql));
    }
    it = stmts.emplace(sql, stmt).first;
  }
  // Map nodes are stable, so the key can back the statement's error text.
  return absl::StatusOr<Statement>(absl::in_place, it->second, &it->first);
}

absl::StatusOr<std::optional<JobRecord>> SqliteJobStore::LoadLocked(Connection& c,
                                                                    const std::string& id) {
  absl::StatusOr<Statement> s = c.Prepare("SELECT " NIMBUS_JOB_COLUMNS " FROM jobs WHERE id = ?1");
  if (!s.ok()) return s.status();
  s->Bind(1, id);
  absl::StatusOr<bool> row = s->Step();
  if (!row.ok()) return row.status();
  if (!*row) return std::optional<JobRecord>();
  return std::optional<JobRecord>(RowToRecord(*s));
}

absl::StatusOr<JobRecord> SqliteJobStore::LoadExistingLocked(Connection& c,
                                                             const std::string& id) {
  absl::StatusOr<std::optional<JobRecord>> r = LoadLocked(c, id);
  if (!r.ok()) return r.status();
  if (!r->has_value())
    return absl::NotFoundError(absl::StrCat("job \"", EchoId(id), "\" not found"));
  return std::move(**r);
}

absl::Status SqliteJobStore::CheckClaimLocked(const std::string& id, const std::string& worker_id) {
  absl::StatusOr<JobRecord> r = LoadExistingLocked(id);
  if (!r.ok()) return r.status();
  if (r->state != JobState::kRunning) {
    return absl::FailedPreconditionError(
        absl::StrCat("job \"", id, "\" is ", StateName(r->state), ", not RUNNING"));
  }
  if (r->worker_id != worker_id) {
    return absl::FailedPreconditionError(absl::StrCat("job \"", id, "\" is claimed by worker \"",
                                                      r->worker_id, "\", not \"", worker_id, "\""));
  }
  return absl::OkStatus();
}

absl::Status SqliteJobStore::CancelOrphansLocked(const char* sql, TimeMs now) {
  absl::StatusOr<Statement> s = Prepare(sql);
  if (!s.ok()) return s.status();
  s->Bind(1, now).Bind(2, JobState::kCancelled).Bind(3, std::string(kCancelledByRequest));
  s->Bind(4, JobState::kRunning).Bind(5, kCancelledCode);
  return s->Run();
}

absl::StatusOr<JobRecord> SqliteJobStore::Create(const NewJob& job, TimeMs now) {
  // The service checks names first; this keeps any caller from storing more.
  if (job.name.size() > kMaxJobNameBytes)
    return absl::InvalidArgumentError(absl::StrCat("name: must be at most ", kMaxJobNameBytes,
                                                   " bytes, got ", job.name.size()));
  if (absl::Status s = CheckPriority(job.priority); !s.ok()) return s;
  std::lock_guard<std::mutex> lock(mu_);
  Transaction txn(this);
  if (absl::Status s = txn.Begin(); !s.ok()) return s;

  if (!job.request_id.empty()) {
    absl::StatusOr<Statement> s =
        Prepare("SELECT " NIMBUS_JOB_COLUMNS " FROM jobs WHERE owner = ?1 AND request_id = ?2");
    if (!s.ok()) return s.status();
    s->Bind(1, job.owner).Bind(2, job.request_id);
    absl::StatusOr<bool> row = s->Step();
    if (!row.ok()) return row.status();
    if (*row) {
      // An idempotent retry gets the original job; the same key for
      // another spec is a client bug that must not pass silently.
      JobRecord existing = RowToRecord(*s);
      if (existing.spec != job.spec)
        return absl::AlreadyExistsError(
            absl::StrCat("request_id ", EchoId(job.request_id), " was already used for another spec (job ",
                         existing.id, ")"));
      return existing;
    }
  }

  if (job.shard_count > 1 && !job.cached_from.empty())
    return absl::InvalidArgumentError("a result-cache hit cannot be sharded");
  const uint32_t shards = job.shard_count > 1 ? job.shard_count : 0;
  {
    absl::StatusOr<Statement> s = Prepare(
        "INSERT INTO jobs (id, name, state, spec, request_id, create_time, progress_total, "
        "warnings, estimated_memory_bytes, owner, shard_count, shards_pending, spec_sha256, "
        "priority, retried_from) "
        "VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?11, ?12, ?13, ?14)");
    if (!s.ok()) return s.status();
    s->Bind(1, job.id).Bind(2, job.name).Bind(3, JobState::kQueued).BindBlob(4, job.spec);
    s->Bind(5, job.request_id).Bind(6, now).Bind(7, job.progress_total);
    s->Bind(8, BoundText(job.warnings, kMaxWarningsBytes));
    s->Bind(9, job.estimated_memory_bytes).Bind(10, job.owner);
    s->Bind(11, int64_t{shards}).Bind(12, job.spec_sha256);
    s->Bind(13, job.priority).Bind(14, job.retried_from);
    if (absl::Status st = s->Run(); !st.ok()) {
      if (st.code() == absl::StatusCode::kAlreadyExists) {
        return absl::AlreadyExistsError(absl::StrCat("job \"", job.id, "\" already exists"));
      }
      return st;
    }
  }
  if (shards > 0)
    if (absl::Status st = InsertShardsLocked(job, now); !st.ok()) return st;
  if (!job.cached_from.empty()) {
    // A cache hit is born finished, with the copied result.
    const Completion& c = job.cached_result;
    absl::StatusOr<Statement> s = Prepare(
        "UPDATE jobs SET state = 3, start_time = ?1, end_time = ?1, "
        "progress_done = progress_total, result_key = ?2, result_size = ?3, "
        "result_sha256 = ?4, cached_from = ?5 WHERE id = ?6");
    if (!s.ok()) return s.status();
    s->Bind(1, now).Bind(2, c.result_key).Bind(3, c.result_size).Bind(4, c.result_sha256);
    s->Bind(5, job.cached_from).Bind(6, job.id);
    if (absl::Status st = s->Run(); !st.ok()) return st;
  }
  if (!job.submitted_by.empty())
    if (absl::Status st = AppendEventLocked(job.id, SubmittedEvent(job, now)); !st.ok()) return st;
  absl::StatusOr<JobRecord> created = LoadExistingLocked(job.id);
  if (!created.ok()) return created.status();
  if (absl::Status s = txn.Commit(); !s.ok()) return s;
  return created;
}

absl::Status SqliteJobStore::InsertShardsLocked(const NewJob& job, TimeMs now) {
  absl::StatusOr<Statement> s = Prepare(
      "INSERT INTO jobs (id, name, state, spec, create_time, progress_total, warnings, "
      "estimated_memory_bytes, owner, parent_id, shard_index, shard_count, spec_sha256, "
      "priority) VALUES (?1, ?2, 1, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13)");
  if (!s.ok()) return s.status();
  for (uint32_t k = 0; k < job.shard_count; ++k) {
    s->Reset();
    s->Bind(1, ShardJobId(job.id, k)).Bind(2, job.name).BindBlob(3, job.spec).Bind(4, now);
    s->Bind(5, job.progress_total).Bind(6, BoundText(job.warnings, kMaxWarningsBytes));
    s->Bind(7, job.estimated_memory_bytes).Bind(8, job.owner).Bind(9, job.id);
    s->Bind(10, int64_t{k}).Bind(11, int64_t{job.shard_count}).Bind(12, job.spec_sha256);
    s->Bind(13, job.priority);
    if (absl::Status st = s->Run(); !st.ok()) return st;
  }
  return absl::OkStatus();
}

absl::Status SqliteJobStore::CancelShardsLocked(const std::string& parent_id, TimeMs now) {
  {
    absl::StatusOr<Statement> s = Prepare(
        "UPDATE jobs SET state = 5, end_time = ?2, error = ?3, cancel_requested = 1, "
        "error_code = ?4 WHERE parent_id = ?1 AND state = 1");
    if (!s.ok()) return s.status();
    s->Bind(1, parent_id).Bind(2, now).Bind(3, std::string(kCancelledByRequest));
    s->Bind(4, kCancelledCode);
    if (absl::Status st = s->Run(); !st.ok()) return st;
  }
  absl::StatusOr<Statement> s =
      Prepare("UPDATE jobs SET cancel_requested = 1 WHERE parent_id = ?1 AND state = 2");
  if (!s.ok()) return s.status();
  s->Bind(1, parent_id);
  return s->Run();
}

absl::Status SqliteJobStore::ShardEndedLocked(const std::string& id, TimeMs now) {
  absl::StatusOr<JobRecord> shard = LoadExistingLocked(id);
  if (!shard.ok()) return shard.status();
  if (shard->parent_id.empty() || !IsTerminal(shard->state)) return absl::OkStatus();
  if (shard->state == JobState::kSucceeded) {
    absl::StatusOr<Statement> s = Prepare(
        "UPDATE jobs SET shards_pending = shards_pending - 1 "
        "WHERE id = ?1 AND shards_pending > 0");
    if (!s.ok()) return s.status();
    s->Bind(1, shard->parent_id);
    return s->Run();
  }
  absl::StatusOr<JobRecord> parent = LoadExistingLocked(shard->parent_id);
  if (!parent.ok()) return parent.status();
  if (IsTerminal(parent->state)) return absl::OkStatus();
  {
    // The parent ends as its shard did, naming it.
    absl::StatusOr<Statement> s = Prepare(
        "UPDATE jobs SET state = ?1, end_time = ?2, error = ?3, error_code = ?4, "
        "worker_id = '', lease_expiry = 0 WHERE id = ?5");
    if (!s.ok()) return s.status();
    s->Bind(1, shard->state).Bind(2, now);
    s->Bind(3, BoundText(absl::StrCat("shard ", shard->shard_index, " of ", shard->shard_count,
                                      ": ", shard->error),
                         kMaxErrorBytes));
    s->Bind(4, shard->error_code).Bind(5, parent->id);
    if (absl::Status st = s->Run(); !st.ok()) return st;
  }
  return CancelShardsLocked(parent->id, now);
}

absl::StatusOr<std::vector<JobRecord>> SqliteJobStore::ListShards(const std::string& parent_id) {
  std::lock_guard<std::mutex> lock(*read_mu_);
  absl::StatusOr<JobRecord> parent = LoadExistingLocked(*r_, parent_id);
  if (!parent.ok()) return parent.status();
  absl::StatusOr<Statement> s = r_->Prepare(
      "SELECT " NIMBUS_JOB_COLUMNS " FROM jobs WHERE parent_id = ?1 ORDER BY shard_index");
  if (!s.ok()) return s.status();
  s->Bind(1, parent_id);
  std::vector<JobRecord> shards;
  while (true) {
    absl::StatusOr<bool> row = s->Step();
    if (!row.ok()) return row.status();
    if (!*row) break;
    shards.push_back(RowToRecord(*s));
  }
  return shards;
}

absl::StatusOr<std::optional<JobRecord>> SqliteJobStore::FindCached(
    const std::string& spec_sha256, const std::string& owner) {
  if (spec_sha256.empty()) return std::optional<JobRecord>();
  std::lock_guard<std::mutex> lock(*read_mu_);
  absl::StatusOr<Statement> s = r_->Prepare(
      "SELECT " NIMBUS_JOB_COLUMNS
      " FROM jobs WHERE spec_sha256 = ?1 AND owner = ?2 AND state = 3 AND "
      "result_expire_time = 0 AND parent_id = '' ORDER BY end_time DESC, rowid DESC LIMIT 1");
  if (!s.ok()) return s.status();
  s->Bind(1, spec_sha256).Bind(2, owner);
  absl::StatusOr<bool> row = s->Step();
  if (!row.ok()) return row.status();
  if (!*row) return std::optional<JobRecord>();
  return std::optional<JobRecord>(RowToRecord(*s));
}

absl::StatusOr<JobRecord> SqliteJobStore::Get(const std::string& id) {
  std::lock_guard<std::mutex> lock(*read_mu_);
  return LoadExistingLocked(*r_, id);
}

absl::StatusOr<ListPage> SqliteJobStore::List(const ListOptions& options) {
  int page_size = options.page_size == 0 ? kDefaultPageSize : options.page_size;
  page_size = std::clamp(page_size, 1, kMaxPageSize);

  const bool has_cursor = !options.page_token.empty();
  TimeMs cursor_time = 0;
  std::string cursor_id;
  if (has_cursor) {
    if (absl::Status s = DecodePageToken(options.page_token, &cursor_time, &cursor_id); !s.ok()) {
      return s;
    }
  }

  // Four fixed shapes rather than "?1 IS NULL OR ..." so each one can use an
  // index for both the filter and the order; the owner (?5, NULL for all)
  // only filters the rows the index walk yields.
#define NIMBUS_OWNER_FILTER "(?5 IS NULL OR owner = ?5) AND (?6 <> 0 OR parent_id = '')"
  const char* sql;
  if (options.state.has_value()) {
    sql = has_cursor ? "SELECT " NIMBUS_JOB_COLUMNS
                       " FROM jobs WHERE state = ?1 AND (create_time, id) < (?2, ?3) "
                       "AND " NIMBUS_OWNER_FILTER " ORDER BY create_time DESC, id DESC LIMIT ?4"
                     : "SELECT " NIMBUS_JOB_COLUMNS
                       " FROM jobs WHERE state = ?1 AND " NIMBUS_OWNER_FILTER
                       " ORDER BY create_time DESC, id DESC LIMIT ?4";
  } else {
    sql = has_cursor ? "SELECT " NIMBUS_JOB_COLUMNS
                       " FROM jobs WHERE (create_time, id) < (?2, ?3) AND " NIMBUS_OWNER_FILTER
                       " ORDER BY create_time DESC, id DESC LIMIT ?4"
                     : "SELECT " NIMBUS_JOB_COLUMNS " FROM jobs WHERE " NIMBUS_OWNER_FILTER
                       " ORDER BY create_time DESC, id DESC LIMIT ?4";
  }
#undef NIMBUS_OWNER_FILTER

  std::lock_guard<std::mutex> lock(*read_mu_);
  absl::StatusOr<Statement> s = r_->Prepare(sql);
  if (!s.ok()) return s.status();
  if (options.state.has_value()) s->Bind(1, *options.state);
  if (has_cursor) s->Bind(2, cursor_time).Bind(3, cursor_id);
  if (options.owner.has_value()) s->Bind(5, *options.owner);
  s->Bind(6, options.include_shards ? 1 : 0);
  // One extra row tells whether another page exists, so the last page never
  // hands out a token that leads to an empty page.
  s->Bind(4, page_size + 1);

  ListPage page;
  uint64_t bytes = 0;
  while (true) {
    absl::StatusOr<bool> row = s->Step();
    if (!row.ok()) return row.status();
    if (!*row) break;
    JobRecord r = RowToRecord(*s);
    const uint64_t more = ViewBytes(r);
    // Full by count or by bytes: the row just read proves a next page.
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
}

absl::StatusOr<std::optional<std::pair<TimeMs, std::string>>>
SqliteJobStore::PickClaimableLocked(TimeMs now) {
  // State values are inlined: they are fixed by the header's enum, and the
  // partial index jobs_claim_order needs its WHERE terms literally.
  static_assert(static_cast<int>(JobState::kQueued) == 1);
  static_assert(static_cast<int>(JobState::kRunning) == 2);
  using Pick = std::optional<std::pair<TimeMs, std::string>>;
  // The highest priority among claimable QUEUED jobs (sqlite_claim_sql.h).
  std::optional<int64_t> top;
  {
    absl::StatusOr<Statement> s = Prepare(kSqliteTopPrioritySql);
    if (!s.ok()) return s.status();
    absl::StatusOr<bool> row = s->Step();
    if (!row.ok()) return row.status();
    if (*row) top = s->Int(0);
  }
  {
    // A RUNNING job whose lease lapsed goes first unless a queued job has a
    // higher priority; running jobs are few (one per worker).
    absl::StatusOr<Statement> s = Prepare(
        "SELECT create_time, id FROM jobs WHERE state = 2 AND cancel_requested = 0 AND "
        "shards_pending = 0 AND lease_expiry < ?1 AND priority >= ?2 "
        "ORDER BY priority DESC, create_time, rowid LIMIT 1");
    if (!s.ok()) return s.status();
    s->Bind(1, now).Bind(2, top.value_or(int64_t{kMinPriority}));
    absl::StatusOr<bool> row = s->Step();
    if (!row.ok()) return row.status();
    if (*row) return Pick(std::pair(s->Int(0), s->Text(1)));
  }
  if (!top.has_value()) return Pick();
  absl::StatusOr<std::optional<OwnerTurn>> turn = NextOwnerTurnLocked(*top);
  if (!turn.ok()) return turn.status();
  if (!turn->has_value()) return Pick();
  return Pick(std::pair((*turn)->create_time, (*turn)->job_id));
}

absl::StatusOr<std::optional<OwnerTurn>> SqliteJobStore::NextOwnerTurnLocked(int64_t priority) {
  // Steps through the owners with claimable jobs at `priority` in owner
  // order, one index seek each (which also finds the owner's oldest job);
  // the cost grows with the owners at that priority, not with their jobs.
  std::optional<OwnerTurn> best;
  std::string owner;
  for (bool first = true;; first = false) {
    OwnerTurn turn;
    {
      absl::StatusOr<Statement> s =
          Prepare(first ? kSqliteOwnerSeekFromSql : kSqliteOwnerSeekAfterSql);
      if (!s.ok()) return s.status();
      s->Bind(1, priority).Bind(2, owner);
      absl::StatusOr<bool> row = s->Step();
      if (!row.ok()) return row.status();
      if (!*row) break;
      owner = s->Text(0);
      turn.create_time = s->Int(1);
      turn.seq = s->Int(2);
      turn.job_id = s->Text(3);
    }
    {
      absl::StatusOr<Statement> s = Prepare(
          "SELECT (SELECT count(*) FROM jobs WHERE state = 2 AND owner = ?1), "
          "(SELECT coalesce(max(last_claim), 0) FROM owner_claims WHERE owner = ?1)");
      if (!s.ok()) return s.status();
      s->Bind(1, owner);
      absl::StatusOr<bool> row = s->Step();
      if (!row.ok()) return row.status();
      turn.running = s->Uint(0);
      turn.last_claim = s->Int(1);
    }
    if (!best.has_value() || turn < *best) best = std::move(turn);
  }
  return best;
}

absl::Status SqliteJobStore::NoteClaimLocked(const std::string& id) {
  absl::StatusOr<Statement> s = Prepare(
      "INSERT INTO owner_claims (owner, last_claim) SELECT owner, "
      "(SELECT coalesce(max(last_claim), 0) + 1 FROM owner_claims) FROM jobs WHERE id = ?1 "
      "ON CONFLICT (owner) DO UPDATE SET last_claim = excluded.last_claim");
  if (!s.ok()) return s.status();
  s->Bind(1, id);
  return s->Run();
}

absl::StatusOr<JobRecord> SqliteJobStore::SetPriority(const std::string& id, int priority) {
  if (absl::Status s = CheckPriority(priority); !s.ok()) return s;
  std::lock_guard<std::mutex> lock(mu_);
  Transaction txn(this);
  if (absl::Status s = txn.Begin(); !s.ok()) return s;
  absl::StatusOr<JobRecord> r = LoadExistingLocked(id);
  if (!r.ok()) return r.status();
  if (r->state != JobState::kQueued)
    return absl::FailedPreconditionError(absl::StrCat("job \"", id, "\" is ", StateName(r->state),
                                                      ": only a QUEUED job's priority can change"));
  {
    // A sharded parent waits QUEUED for its shards: the queued ones follow.
    absl::StatusOr<Statement> s =
        Prepare("UPDATE jobs SET priority = ?1 WHERE id = ?2 OR (parent_id = ?2 AND state = 1)");
    if (!s.ok()) return s.status();
    s->Bind(1, priority).Bind(2, id);
    if (absl::Status st = s->Run(); !st.ok()) return st;
  }
  absl::StatusOr<JobRecord> changed = LoadExistingLocked(id);
  if (!changed.ok()) return changed.status();
  if (absl::Status s = txn.Commit(); !s.ok()) return s;
  return changed;
}

absl::Status SqliteJobStore::GiveUpLocked(const std::string& id, uint32_t attempts, TimeMs now) {
  absl::StatusOr<Statement> s = Prepare(
      "UPDATE jobs SET state = ?1, end_time = ?2, worker_id = '', lease_expiry = 0, "
      "error = CASE WHEN error = '' THEN ?3 ELSE ?4 || error END, "
      "error_code = CASE WHEN error_code <> 0 THEN error_code ELSE ?5 END WHERE id = ?6");
  if (!s.ok()) return s.status();
  s->Bind(1, JobState::kFailed).Bind(2, now);
  s->Bind(3, absl::StrCat("gave up after ", attempts,
                          " attempts: none recorded an end (the worker stopped or lost its "
                          "claim)"));
  s->Bind(4, absl::StrCat("gave up after ", attempts, " attempts; the last one: "));
  s->Bind(5, static_cast<int>(absl::StatusCode::kInternal)).Bind(6, id);
  return s->Run();
}

absl::StatusOr<std::optional<JobRecord>> SqliteJobStore::ClaimNext(
    const std::string& worker_id, TimeMs now, TimeMs lease_ms, uint32_t max_attempts,
    std::vector<JobRecord>* given_up) {
  std::lock_guard<std::mutex> lock(mu_);
  Transaction txn(this);
  if (absl::Status s = txn.Begin(); !s.ok()) return s;

  if (absl::Status s = CancelOrphansLocked(
          "UPDATE jobs SET end_time = ?1, state = ?2, error = ?3, error_code = ?5, "
          "worker_id = '', lease_expiry = 0 "
          "WHERE state = ?4 AND cancel_requested <> 0 AND lease_expiry < ?1",
          now);
      !s.ok()) {
    return s;
  }

  std::optional<std::pair<TimeMs, std::string>> best;
  while (true) {
    absl::StatusOr<std::optional<std::pair<TimeMs, std::string>>> pick = PickClaimableLocked(now);
    if (!pick.ok()) return pick.status();
    best = std::move(*pick);
    if (!best.has_value() || max_attempts == 0) break;
    absl::StatusOr<JobRecord> r = LoadExistingLocked(best->second);
    if (!r.ok()) return r.status();
    if (r->attempts < max_attempts) break;
    // Out of attempts: fail it and look again (each pass ends one job).
    if (absl::Status s = GiveUpLocked(best->second, r->attempts, now); !s.ok()) return s;
    if (absl::Status s = ShardEndedLocked(best->second, now); !s.ok()) return s;
    if (given_up != nullptr) {
      absl::StatusOr<JobRecord> failed = LoadExistingLocked(best->second);
      if (!failed.ok()) return failed.status();
      given_up->push_back(std::move(*failed));
    }
  }
  if (!best.has_value()) {
    // Still commit: the orphan cancellations and give-ups above must stick.
    if (absl::Status s = txn.Commit(); !s.ok()) return s;
    return std::optional<JobRecord>();
  }

  absl::StatusOr<JobRecord> before = LoadExistingLocked(best->second);
  if (!before.ok()) return before.status();
  if (before->state == JobState::kRunning) {
    // Its worker stopped heartbeating: the event log says so.
    if (absl::Status s =
            AppendEventLocked(before->id, {0,
                                           now,
                                           "lease_lost",
                                           {{"worker", before->worker_id},
                                            {"attempt", absl::StrCat(before->attempts)},
                                            {"lease_expiry", absl::StrCat(before->lease_expiry)}}});
        !s.ok())
      return s;
  }
  {
    // progress_done restarts with the new attempt; the total is unchanged.
    absl::StatusOr<Statement> s = Prepare(
        "UPDATE jobs SET state = ?1, worker_id = ?2, lease_expiry = ?3, start_time = ?4, "
        "attempts = attempts + 1, progress_done = 0 WHERE id = ?5");
    if (!s.ok()) return s.status();
    s->Bind(1, JobState::kRunning).Bind(2, worker_id).Bind(3, now + lease_ms).Bind(4, now);
    s->Bind(5, best->second);
    if (absl::Status st = s->Run(); !st.ok()) return st;
  }
  if (absl::Status s = NoteClaimLocked(best->second); !s.ok()) return s;
  if (absl::Status s = AppendEventLocked(
          best->second, {0,
                         now,
                         "claimed",
                         {{"worker", worker_id}, {"attempt", absl::StrCat(before->attempts + 1)}}});
      !s.ok())
    return s;
  absl::StatusOr<JobRecord> claimed = LoadExistingLocked(best->second);
  if (!claimed.ok()) return claimed.status();
  if (absl::Status s = txn.Commit(); !s.ok()) return s;
  return std::optional<JobRecord>(std::move(*claimed));
}

absl::StatusOr<bool> SqliteJobStore::Heartbeat(const std::string& id, const std::string& worker_id,
                                               TimeMs now, TimeMs lease_ms, uint64_t progress_done,
                                               uint64_t progress_total) {
  std::lock_guard<std::mutex> lock(mu_);
  Transaction txn(this);
  if (absl::Status s = txn.Begin(); !s.ok()) return s;
  if (absl::Status s = CheckClaimLocked(id, worker_id); !s.ok()) return s;

  bool cancel_requested = false;
  {
    absl::StatusOr<Statement> s = Prepare(
        "UPDATE jobs SET lease_expiry = ?1, progress_done = ?2, progress_total = ?3 "
        "WHERE id = ?4");
    if (!s.ok()) return s.status();
    s->Bind(1, now + lease_ms).Bind(2, progress_done).Bind(3, progress_total).Bind(4, id);
    if (absl::Status st = s->Run(); !st.ok()) return st;
  }
  {
    absl::StatusOr<Statement> s = Prepare("SELECT cancel_requested FROM jobs WHERE id = ?1");
    if (!s.ok()) return s.status();
    s->Bind(1, id);
    absl::StatusOr<bool> row = s->Step();
    if (!row.ok()) return row.status();
    cancel_requested = *row && s->Int(0) != 0;
  }
  if (absl::Status s = txn.Commit(); !s.ok()) return s;
  return cancel_requested;
}

absl::Status SqliteJobStore::Complete(const std::string& id, const std::string& worker_id,
                                      const Completion& completion, TimeMs now) {
  if (!IsTerminal(completion.state)) {
    return absl::InvalidArgumentError(absl::StrCat("cannot complete job \"", id, "\" as ",
                                                   StateName(completion.state),
                                                   ": not a terminal state"));
  }
  std::lock_guard<std::mutex> lock(mu_);
  Transaction txn(this);
  if (absl::Status s = txn.Begin(); !s.ok()) return s;
  if (absl::Status s = CheckClaimLocked(id, worker_id); !s.ok()) return s;

  {
    // Empty completion warnings keep the ones recorded at submit time.
    absl::StatusOr<Statement> s = Prepare(
        "UPDATE jobs SET state = ?1, end_time = ?2, error = ?3, result_key = ?4, "
        "result_size = ?5, result_sha256 = ?6, "
        "warnings = CASE WHEN ?7 = '' THEN warnings ELSE ?7 END, "
        "worker_id = '', lease_expiry = 0, error_code = ?9 WHERE id = ?8");
    if (!s.ok()) return s.status();
    s->Bind(1, completion.state).Bind(2, now).Bind(3, BoundText(completion.error, kMaxErrorBytes));
    s->Bind(4, completion.result_key).Bind(5, completion.result_size);
    s->Bind(6, completion.result_sha256);
    s->Bind(7, BoundText(completion.warnings, kMaxWarningsBytes)).Bind(8, id);
    s->Bind(9, completion.error_code);
    if (absl::Status st = s->Run(); !st.ok()) return st;
  }
  if (absl::Status st = ShardEndedLocked(id, now); !st.ok()) return st;
  if (absl::Status st = AppendEventLocked(id, EndEvent(worker_id, completion, now)); !st.ok())
    return st;
  return txn.Commit();
}

absl::Status SqliteJobStore::AbandonAttempt(const std::string& id, const std::string& worker_id,
                                            const std::string& error, int error_code) {
  return GiveBack(id, worker_id, AttemptEnd{BoundText(error, kMaxErrorBytes), error_code});
}

absl::Status SqliteJobStore::Release(const std::string& id, const std::string& worker_id) {
  return GiveBack(id, worker_id, std::nullopt);
}

absl::Status SqliteJobStore::GiveBack(const std::string& id, const std::string& worker_id,
                                      const std::optional<AttemptEnd>& attempt) {
  std::lock_guard<std::mutex> lock(mu_);
  Transaction txn(this);
  if (absl::Status s = txn.Begin(); !s.ok()) return s;
  if (absl::Status s = CheckClaimLocked(id, worker_id); !s.ok()) return s;
  {
    // Back to QUEUED (keeping the attempt's error when one is given). A
    // job whose cancel was already requested is not worth requeueing, and
    // as QUEUED it would never be claimed (or finished) again: it ends
    // CANCELLED.
    absl::StatusOr<Statement> s = Prepare(
        "UPDATE jobs SET worker_id = '', lease_expiry = 0, "
        "state = CASE WHEN cancel_requested <> 0 THEN ?1 ELSE ?2 END, "
        "error = CASE WHEN cancel_requested <> 0 THEN ?3 WHEN ?8 <> 0 THEN ?4 ELSE error END, "
        "error_code = CASE WHEN cancel_requested <> 0 THEN ?5 WHEN ?8 <> 0 THEN ?6 "
        "ELSE error_code END WHERE id = ?7");
    if (!s.ok()) return s.status();
    s->Bind(1, JobState::kCancelled).Bind(2, JobState::kQueued);
    s->Bind(3, std::string(kCancelledByRequest)).Bind(4, attempt ? attempt->error : std::string());
    s->Bind(5, kCancelledCode).Bind(6, attempt ? attempt->code : 0).Bind(7, id);
    s->Bind(8, attempt ? 1 : 0);
    if (absl::Status st = s->Run(); !st.ok()) return st;
  }
  if (absl::Status st = ShardEndedLocked(id, WallClockMs()); !st.ok()) return st;
  return txn.Commit();
}

absl::StatusOr<JobRecord> SqliteJobStore::RequestCancel(const std::string& id, TimeMs now,
                                                        const std::string& by) {
  std::lock_guard<std::mutex> lock(mu_);
  Transaction txn(this);
  if (absl::Status s = txn.Begin(); !s.ok()) return s;
  absl::StatusOr<JobRecord> job = LoadExistingLocked(id);
  if (!job.ok()) return job.status();
  if (IsTerminal(job->state)) return job;  // Nothing to do; no write.

  const char* sql =
      job->state == JobState::kQueued
          ? "UPDATE jobs SET state = ?1, end_time = ?2, error = ?3, cancel_requested = 1, "
            "error_code = ?5 WHERE id = ?4"
          : "UPDATE jobs SET cancel_requested = 1 WHERE id = ?4";
  {
    absl::StatusOr<Statement> s = Prepare(sql);
    if (!s.ok()) return s.status();
    if (job->state == JobState::kQueued) {
      s->Bind(1, JobState::kCancelled).Bind(2, now).Bind(3, std::string(kCancelledByRequest));
      s->Bind(5, kCancelledCode);
    }
    s->Bind(4, id);
    if (absl::Status st = s->Run(); !st.ok()) return st;
  }
  if (job->state == JobState::kQueued)
    if (absl::Status st = AppendEventLocked(id, QueuedCancelEvent(by, now)); !st.ok()) return st;
  // A parent's cancel reaches its shards; a shard cancelled while queued
  // ends its parent.
  if (job->shard_count > 1 && job->parent_id.empty())
    if (absl::Status st = CancelShardsLocked(id, now); !st.ok()) return st;
  if (absl::Status st = ShardEndedLocked(id, now); !st.ok()) return st;
  job = LoadExistingLocked(id);
  if (!job.ok()) return job.status();
  if (absl::Status s = txn.Commit(); !s.ok()) return s;
  return job;
}

absl::StatusOr<int> SqliteJobStore::RequeueRunning() {
  std::lock_guard<std::mutex> lock(mu_);
  Transaction txn(this);
  if (absl::Status s = txn.Begin(); !s.ok()) return s;

  // Cancel-requested jobs end as CANCELLED instead: requeued, they could
  // never be claimed, so they would sit in QUEUED forever.
  static_assert(static_cast<int>(JobState::kRunning) == 2);
  if (absl::Status s = CancelOrphansLocked(
          "UPDATE jobs SET end_time = ?1, state = ?2, error = ?3, error_code = ?5, "
          "worker_id = '', lease_expiry = 0 WHERE state = ?4 AND cancel_requested <> 0",
          WallClockMs());
      !s.ok()) {
    return s;
  }
  {
    // Each requeued job's log says whose claim ended.
    std::vector<std::pair<std::string, std::string>> held;
    absl::StatusOr<Statement> s = Prepare("SELECT id, worker_id FROM jobs WHERE state = 2");
    if (!s.ok()) return s.status();
    for (;;) {
      absl::StatusOr<bool> row = s->Step();
      if (!row.ok()) return row.status();
      if (!*row) break;
      held.emplace_back(s->Text(0), s->Text(1));
    }
    s->Reset();
    for (const auto& [id, worker] : held)
      if (absl::Status st = AppendEventLocked(
              id, {0, WallClockMs(), "lease_lost", {{"worker", worker}, {"reason", "restart"}}});
          !st.ok())
        return st;
  }
  int requeued = 0;
  {
    absl::StatusOr<Statement> s =
        Prepare("UPDATE jobs SET state = ?1, worker_id = '', lease_expiry = 0 WHERE state = ?2");
    if (!s.ok()) return s.status();
    s->Bind(1, JobState::kQueued).Bind(2, JobState::kRunning);
    if (absl::Status st = s->Run(); !st.ok()) return st;
    requeued = sqlite3_changes(w_.db);
  }
  if (absl::Status s = txn.Commit(); !s.ok()) return s;
  return requeued;
}

absl::StatusOr<OwnerUsage> SqliteJobStore::Usage(const std::string& owner) {
  std::lock_guard<std::mutex> lock(*read_mu_);
  absl::StatusOr<Statement> s = r_->Prepare(
      "SELECT count(*) FILTER (WHERE state IN (1, 2)), "
      "coalesce(sum(result_size) FILTER (WHERE state = 3 AND result_expire_time = 0), 0) "
      "FROM jobs WHERE owner = ?1 AND parent_id = ''");
  if (!s.ok()) return s.status();
  s->Bind(1, owner);
  absl::StatusOr<bool> row = s->Step();
  if (!row.ok()) return row.status();
  OwnerUsage u;
  if (*row) {
    u.active_jobs = s->Uint(0);
    u.result_bytes = s->Uint(1);
  }
  return u;
}

absl::StatusOr<JobRecord> SqliteJobStore::SetPinned(const std::string& id, bool pinned) {
  std::lock_guard<std::mutex> lock(mu_);
  Transaction txn(this);
  if (absl::Status s = txn.Begin(); !s.ok()) return s;
  {
    absl::StatusOr<Statement> s = Prepare("UPDATE jobs SET pinned = ?1 WHERE id = ?2");
    if (!s.ok()) return s.status();
    s->Bind(1, pinned ? 1 : 0).Bind(2, id);
    if (absl::Status st = s->Run(); !st.ok()) return st;
  }
  absl::StatusOr<JobRecord> job = LoadExistingLocked(id);
  if (!job.ok()) return job.status();
  if (absl::Status s = txn.Commit(); !s.ok()) return s;
  return job;
}

absl::Status SqliteJobStore::Delete(const std::string& id) {
  std::lock_guard<std::mutex> lock(mu_);
  Transaction txn(this);
  if (absl::Status s = txn.Begin(); !s.ok()) return s;
  absl::StatusOr<JobRecord> job = LoadExistingLocked(id);
  if (!job.ok()) return job.status();
  if (!IsTerminal(job->state))
    return absl::FailedPreconditionError(
        absl::StrCat("job ", id, " is ", StateName(job->state), "; cancel it before deleting it"));
  {
    absl::StatusOr<Statement> s =
        Prepare("SELECT count(*) FROM jobs WHERE parent_id = ?1 AND state IN (1, 2)");
    if (!s.ok()) return s.status();
    s->Bind(1, id);
    absl::StatusOr<bool> row = s->Step();
    if (!row.ok()) return row.status();
    if (*row && s->Int(0) > 0)
      return absl::FailedPreconditionError(
          absl::StrCat("job ", id, " still has ", s->Int(0), " active shards"));
  }
  {
    // A parent goes with its shards.
    absl::StatusOr<Statement> s = Prepare("DELETE FROM jobs WHERE id = ?1 OR parent_id = ?1");
    if (!s.ok()) return s.status();
    s->Bind(1, id);
    if (absl::Status st = s->Run(); !st.ok()) return st;
  }
  {
    // And its event log.
    absl::StatusOr<Statement> s = Prepare("DELETE FROM job_events WHERE job_id = ?1");
    if (!s.ok()) return s.status();
    s->Bind(1, id);
    if (absl::Status st = s->Run(); !st.ok()) return st;
  }
  return txn.Commit();
}

absl::StatusOr<std::vector<JobRecord>> SqliteJobStore::ListExpiring(TimeMs cutoff, int limit) {
  std::lock_guard<std::mutex> lock(*read_mu_);
  absl::StatusOr<Statement> s =
      r_->Prepare("SELECT " NIMBUS_JOB_COLUMNS
                  " FROM jobs WHERE state = 3 AND pinned = 0 AND "
                  "result_expire_time = 0 AND end_time < ?1 AND parent_id = '' "
                  "ORDER BY end_time LIMIT ?2");
  if (!s.ok()) return s.status();
  s->Bind(1, cutoff).Bind(2, limit);
  std::vector<JobRecord> jobs;
  while (true) {
    absl::StatusOr<bool> row = s->Step();
    if (!row.ok()) return row.status();
    if (!*row) break;
    jobs.push_back(RowToRecord(*s));
  }
  return jobs;
}

absl::Status SqliteJobStore::MarkResultExpired(const std::string& id, TimeMs now) {
  std::lock_guard<std::mutex> lock(mu_);
  absl::StatusOr<Statement> s =
      Prepare("UPDATE jobs SET result_expire_time = ?1 WHERE id = ?2 AND state = 3");
  if (!s.ok()) return s.status();
  s->Bind(1, now).Bind(2, id);
  return s->Run();
}

absl::StatusOr<std::vector<std::string>> SqliteJobStore::SpecsInUse() {
  std::lock_guard<std::mutex> lock(*read_mu_);
  absl::StatusOr<Statement> s =
      r_->Prepare("SELECT spec FROM jobs WHERE state IN (1, 2) OR pinned <> 0");
  if (!s.ok()) return s.status();
  std::vector<std::string> specs;
  while (true) {
    absl::StatusOr<bool> row = s->Step();
    if (!row.ok()) return row.status();
    if (!*row) break;
    specs.push_back(s->Blob(0));
  }
  return specs;
}

absl::StatusOr<PokeRecord> SqliteJobStore::AddPoke(const std::string& id, const PokeRecord& poke) {
  std::lock_guard<std::mutex> lock(mu_);
  Transaction txn(this);
  if (absl::Status s = txn.Begin(); !s.ok()) return s;
  absl::StatusOr<JobRecord> job = LoadExistingLocked(id);
  if (!job.ok()) return job.status();
  if (job->state != JobState::kRunning)
    return absl::FailedPreconditionError(absl::StrCat("job ", EchoId(id), " is ",
                                                      StateName(job->state),
                                                      "; pokes act on RUNNING jobs only"));
  {
    absl::StatusOr<Statement> s = Prepare(
        "INSERT INTO pokes (job_id, frame, body, drag, x, y, z, drag_stiffness, drag_frames) "
        "VALUES (?1, -1, ?2, ?3, ?4, ?5, ?6, ?7, ?8)");
    if (!s.ok()) return s.status();
    s->Bind(1, id).Bind(2, int64_t{poke.body}).Bind(3, int64_t{poke.drag});
    s->BindDouble(4, poke.x).BindDouble(5, poke.y).BindDouble(6, poke.z);
    s->BindDouble(7, poke.drag_stiffness).Bind(8, int64_t{poke.drag_frames});
    if (absl::Status st = s->Run(); !st.ok()) return st;
  }
  PokeRecord out = poke;
  out.seq = sqlite3_last_insert_rowid(w_.db);
  out.frame = -1;
  if (absl::Status s = txn.Commit(); !s.ok()) return s;
  return out;
}

absl::StatusOr<std::vector<PokeRecord>> SqliteJobStore::TakePokes(const std::string& id,
                                                                  const std::string& worker_id,
                                                                  int64_t frame) {
  std::lock_guard<std::mutex> lock(mu_);
  Transaction txn(this);
  if (absl::Status s = txn.Begin(); !s.ok()) return s;
  if (absl::Status s = CheckClaimLocked(id, worker_id); !s.ok()) return s;
  {
    absl::StatusOr<Statement> s =
        Prepare("UPDATE pokes SET frame = ?2 WHERE job_id = ?1 AND frame < 0");
    if (!s.ok()) return s.status();
    s->Bind(1, id).Bind(2, frame);
    if (absl::Status st = s->Run(); !st.ok()) return st;
  }
  std::vector<PokeRecord> out;
  {
    absl::StatusOr<Statement> s = Prepare(
        "SELECT seq, frame, body, drag, x, y, z, drag_stiffness, drag_frames FROM pokes "
        "WHERE job_id = ?1 AND frame = ?2 ORDER BY seq");
    if (!s.ok()) return s.status();
    s->Bind(1, id).Bind(2, frame);
    for (;;) {
      absl::StatusOr<bool> row = s->Step();
      if (!row.ok()) return row.status();
      if (!*row) break;
      out.push_back({s->Int(0), s->Int(1), int32_t(s->Int(2)), s->Int(3) != 0, s->Double(4),
                     s->Double(5), s->Double(6), s->Double(7), uint32_t(s->Int(8))});
    }
  }
  if (absl::Status s = txn.Commit(); !s.ok()) return s;
  return out;
}

absl::StatusOr<int> SqliteJobStore::RunWrite(const char* sql,
                                             const std::function<void(Statement&)>& bind) {
  std::lock_guard<std::mutex> lock(mu_);
  absl::StatusOr<Statement> s = Prepare(sql);
  if (!s.ok()) return s.status();
  bind(*s);
  if (absl::Status st = s->Run(); !st.ok()) return st;
  return sqlite3_changes(w_.db);
}

absl::Status SqliteJobStore::RegisterWorker(const WorkerInfo& w) {
  return RunWrite(
             "INSERT OR REPLACE INTO workers (replica_id, host, version, start_time, "
             "worker_slots, threads_per_job, jobs_running, last_heartbeat) "
             "VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8)",
             [&](Statement& s) {
               s.Bind(1, w.replica_id).Bind(2, w.host).Bind(3, w.version);
               s.Bind(4, w.start_time).Bind(5, int64_t{w.worker_slots});
               s.Bind(6, int64_t{w.threads_per_job}).Bind(7, int64_t{w.jobs_running});
               s.Bind(8, w.last_heartbeat);
             })
      .status();
}

absl::Status SqliteJobStore::RenewWorker(const std::string& replica_id, uint32_t jobs_running,
                                         int64_t now) {
  absl::StatusOr<int> changed = RunWrite(
      "UPDATE workers SET jobs_running = ?2, last_heartbeat = ?3 WHERE replica_id = ?1",
      [&](Statement& s) { s.Bind(1, replica_id).Bind(2, int64_t{jobs_running}).Bind(3, now); });
  if (!changed.ok()) return changed.status();
  if (*changed == 0)
    return absl::NotFoundError(absl::StrCat("replica \"", replica_id, "\" is not registered"));
  return absl::OkStatus();
}

absl::Status SqliteJobStore::UnregisterWorker(const std::string& replica_id) {
  return RunWrite("DELETE FROM workers WHERE replica_id = ?1",
                  [&](Statement& s) { s.Bind(1, replica_id); })
      .status();
}

absl::StatusOr<int> SqliteJobStore::PruneWorkers(int64_t cutoff) {
  return RunWrite("DELETE FROM workers WHERE last_heartbeat < ?1",
                  [&](Statement& s) { s.Bind(1, cutoff); });
}

absl::StatusOr<std::vector<WorkerInfo>> SqliteJobStore::ListWorkers() {
  std::lock_guard<std::mutex> lock(*read_mu_);
  absl::StatusOr<Statement> s = r_->Prepare(
      "SELECT replica_id, host, version, start_time, worker_slots, threads_per_job, "
      "jobs_running, last_heartbeat FROM workers ORDER BY replica_id");
  if (!s.ok()) return s.status();
  std::vector<WorkerInfo> out;
  for (;;) {
    absl::StatusOr<bool> row = s->Step();
    if (!row.ok()) return row.status();
    if (!*row) break;
    out.push_back({s->Text(0), s->Text(1), s->Text(2), s->Int(3), uint32_t(s->Int(4)),
                   uint32_t(s->Int(5)), uint32_t(s->Int(6)), s->Int(7)});
  }
  return out;
}

absl::Status SqliteJobStore::AppendEvent(const std::string& job_id, const JobEvent& event) {
  std::lock_guard<std::mutex> lock(mu_);
  Transaction txn(this);
  if (absl::Status s = txn.Begin(); !s.ok()) return s;
  if (absl::Status s = AppendEventLocked(job_id, event); !s.ok()) return s;
  return txn.Commit();
}

absl::Status SqliteJobStore::AppendEventLocked(const std::string& job_id, const JobEvent& event) {
  {
    absl::StatusOr<Statement> s = Prepare(
        "INSERT INTO job_events (job_id, seq, time, kind, fields) "
        "SELECT ?1, coalesce(max(seq), 0) + 1, ?2, ?3, ?4 FROM job_events WHERE job_id = ?1");
    if (!s.ok()) return s.status();
    s->Bind(1, job_id).Bind(2, event.time).Bind(3, BoundText(event.kind, kMaxEventFieldBytes));
    s->Bind(4, EncodeEventFields(event.fields));
    if (absl::Status st = s->Run(); !st.ok()) return st;
  }
  // The newest kMaxEventsPerJob stay; seqs stay contiguous, so the first
  // one kept tells how many were dropped.
  absl::StatusOr<Statement> s = Prepare(
      "DELETE FROM job_events WHERE job_id = ?1 AND seq <= "
      "(SELECT max(seq) FROM job_events WHERE job_id = ?1) - ?2");
  if (!s.ok()) return s.status();
  s->Bind(1, job_id).Bind(2, kMaxEventsPerJob);
  return s->Run();
}

absl::StatusOr<JobEventPage> SqliteJobStore::ListEvents(const std::string& job_id, int64_t after,
                                                        int limit) {
  limit = std::clamp(limit <= 0 ? kDefaultPageSize : limit, 1, kMaxPageSize);
  std::lock_guard<std::mutex> lock(*read_mu_);
  JobEventPage page;
  {
    absl::StatusOr<Statement> s =
        r_->Prepare("SELECT coalesce(min(seq), 1) - 1 FROM job_events WHERE job_id = ?1");
    if (!s.ok()) return s.status();
    s->Bind(1, job_id);
    absl::StatusOr<bool> row = s->Step();
    if (!row.ok()) return row.status();
    page.dropped = *row ? s->Int(0) : 0;
  }
  absl::StatusOr<Statement> s = r_->Prepare(
      "SELECT seq, time, kind, fields FROM job_events WHERE job_id = ?1 AND seq > ?2 "
      "ORDER BY seq LIMIT ?3");
  if (!s.ok()) return s.status();
  s->Bind(1, job_id).Bind(2, after).Bind(3, limit + 1);
  for (;;) {
    absl::StatusOr<bool> row = s->Step();
    if (!row.ok()) return row.status();
    if (!*row) break;
    if (static_cast<int>(page.events.size()) == limit) {
      page.next_after = page.events.back().seq;
      break;
    }
    page.events.push_back({s->Int(0), s->Int(1), s->Text(2), DecodeEventFields(s->Text(3))});
  }
  return page;
}

absl::StatusOr<std::unique_ptr<JobStore>> OpenSqliteJobStore(const std::string& path) {
  return SqliteJobStore::Open(path);
}

#undef NIMBUS_JOB_COLUMNS

}  // namespace nimbus::server
