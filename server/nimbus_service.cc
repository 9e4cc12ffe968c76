#include "server/nimbus_service.h"

#include <malloc.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <mutex>
#include <optional>
#include <random>

#include "absl/strings/str_cat.h"
#include "proto/spec_convert.h"
#include "proto/spec_shape.h"
#include "server/access.h"
#include "server/bounded_text.h"
#include "server/job_store_util.h"
#include "server/job_view.h"
#include "server/memory_admission.h"
#include "server/result_export.h"
#include "server/shard_runner.h"
#include "server/untrusted_file.h"

namespace nimbus::server {

namespace {

constexpr uint64_t kFetchChunk = uint64_t{1} << 20;

std::string NewJobId() {
  static thread_local std::mt19937_64 rng(std::random_device{}() ^
                                          uint64_t(NowMs()) * 0x9e3779b97f4a7c15ULL);
  static const char* kHex = "0123456789abcdef";
  std::string id = "j-";
  uint64_t v = rng();
  for (int i = 0; i < 16; ++i, v >>= 4) id.push_back(kHex[v & 15]);
  return id;
}

grpc::Status Busy(const BlockingExecutor& blocking) {
  return grpc::Status(grpc::StatusCode::RESOURCE_EXHAUSTED,
                      absl::StrCat("server busy: ", blocking.max_pending(),
                                   " store and file operations are waiting; retry shortly"));
}

// A streaming call answered with an error before it starts (an unknown
// caller, no asset store).
template <class Reactor>
class Refused : public Reactor {
 public:
  explicit Refused(const grpc::Status& s) { this->Finish(s); }
  void OnDone() override { delete this; }
};

// Who calls; an unknown caller is logged by peer (never by token).
absl::StatusOr<Principal> Authenticate(const TokenTable& tokens,
                                       const grpc::CallbackServerContext& ctx) {
  auto p = tokens.Authenticate(AuthorizationOf(ctx));
  if (!p.ok()) spdlog::warn("event=unauthenticated peer={}", ctx.peer());
  return p;
}

bool IsTerminal(v1::JobState s) {
  return s == v1::JOB_STATE_SUCCEEDED || s == v1::JOB_STATE_FAILED || s == v1::JOB_STATE_CANCELLED;
}

// Adds the result's further files (book pages) to a job view: the committed
// list once it succeeded, the pages finished so far while it runs. Reads the
// disk, so only ever called on the blocking executor.
void AddResultFiles(ResultStore* results, v1::Job& job) {
  const bool running = job.state() == v1::JOB_STATE_RUNNING;
  if (!running && job.state() != v1::JOB_STATE_SUCCEEDED) return;
  std::vector<StoredFile> files = results->ListFiles(job.id(), running);
  if (files.empty()) return;
  v1::ResultInfo* r = job.mutable_result();
  r->clear_files();
  for (const StoredFile& f : files) {
    v1::ResultFile* out = r->add_files();
    out->set_file_name(f.name);
    out->set_size_bytes(f.size);
    out->set_sha256(f.sha256);
  }
}

// Streams job snapshots to one watcher. Holds only the newest snapshot, so a
// slow client skips intermediate states instead of queueing them.
//
// Reading the store and listing result files happen on the blocking
// executor. One "turn" (the start step, a queued or running Pump, or a write
// in flight) exists at a time; only its holder may finish the call, so the
// reactor is never deleted while a task of its own is still queued.
class WatchReactor : public grpc::ServerWriteReactor<v1::WatchJobResponse> {
 public:
  WatchReactor(JobHub* hub, JobStore* store, ResultStore* results, BlockingExecutor* blocking,
               const v1::WatchJobRequest& req, Principal caller)
      : caller_(std::move(caller)),
        hub_(hub),
        store_(store),
        results_(results),
        blocking_(blocking),
        job_id_(req.job_id()),
        resolution_(req.preview_resolution()),
        interval_(req.preview_interval_seconds() > 0 ? req.preview_interval_seconds() : 1.0),
        include_events_(req.include_events()),
        sent_event_seq_(std::max<int64_t>(req.events_after_seq(), 0)) {
    std::lock_guard<std::mutex> lock(mu_);
    busy_ = true;  // the start step holds the turn
    if (!blocking_->Post([this] { Start(); })) FinishLocked(Busy(*blocking_));
  }

  void OnWriteDone(bool ok) override {
    std::lock_guard<std::mutex> lock(mu_);
    if (!ok || sent_terminal_) return FinishLocked(grpc::Status::OK);
    if (cancelled_) return FinishLocked(grpc::Status::CANCELLED);
    busy_ = false;
    KickLocked();
  }

  void OnCancel() override {
    std::lock_guard<std::mutex> lock(mu_);
    cancelled_ = true;
    if (!busy_) FinishLocked(grpc::Status::CANCELLED);
  }

  void OnDone() override {
    if (subscribed_) hub_->Unsubscribe(job_id_, subscription_);
    delete this;
  }

 private:
  // Executor: the store's record first, then the hub's live snapshots.
  void Start() {
    auto rec = LoadVisibleJob(*store_, caller_, job_id_);
    if (!rec.ok()) {
      std::lock_guard<std::mutex> lock(mu_);
      return FinishLocked(ToGrpc(rec.status()));
    }
    v1::Job initial = ToProto(*rec, false);
    // A sharded parent's live view (shards summed) may say RUNNING while
    // its record still waits QUEUED for the merge.
    const bool parent = rec->shard_count > 1 && rec->parent_id.empty();
    if (auto live = hub_->Latest(job_id_);
        live && (live->state() == initial.state() ||
                 (parent && rec->state == JobState::kQueued && !IsTerminal(live->state()))))
      initial = *live;
    {
      std::lock_guard<std::mutex> lock(mu_);
      if (cancelled_) return FinishLocked(grpc::Status::CANCELLED);
      latest_.job = std::make_shared<v1::Job>(std::move(initial));
      pending_ = true;
    }
    // Snapshots arriving now only mark themselves pending: we hold the turn.
    subscription_ = hub_->Subscribe(job_id_, resolution_, interval_,
                                    [this](const JobSnapshot& s) { OnSnapshot(s); });
    subscribed_ = true;
    // The job may have finished (and left the hub) between the first read
    // and the subscription: read the store once more so we never wait forever.
    if (auto again = store_->Get(job_id_); again.ok() && IsTerminal(ToProto(again->state))) {
      JobSnapshot s;
      s.job = std::make_shared<v1::Job>(ToProto(*again, false));
      OnSnapshot(s);
    }
    Pump();
  }

  // Hub side (under the hub's lock): keep the newest, wake the pump.
  void OnSnapshot(const JobSnapshot& s) {
    std::lock_guard<std::mutex> lock(mu_);
    if (!s.job || sent_terminal_ || finished_) return;
    if (latest_.job && IsTerminal(latest_.job->state()) && !IsTerminal(s.job->state())) return;
    // Keep the preview we have when a snapshot without one arrives.
    auto preview = s.preview ? s.preview : latest_.preview;
    latest_ = s;
    latest_.preview = preview;
    pending_ = true;
    KickLocked();
  }

  // Takes the turn and queues a Pump if something new waits to be sent.
  void KickLocked() {
    if (busy_ || finished_ || !pending_) return;
    busy_ = true;
    if (!blocking_->Post([this] { Pump(); })) FinishLocked(Busy(*blocking_));
  }

  // Executor, holding the turn: writes the newest state if it differs from
  // what the client has, or gives the turn back.
  void Pump() {
    JobSnapshot s;
    bool send_preview = false;
    bool send_job = false;
    {
      std::lock_guard<std::mutex> lock(mu_);
      if (cancelled_) return FinishLocked(grpc::Status::CANCELLED);
      pending_ = false;
      s = latest_;
      const v1::Job& job = *s.job;
      const bool job_changed = !sent_job_ || job.state() != sent_state_ ||
                               job.progress().done() != sent_done_ ||
                               job.attempts() != sent_attempts_;
      if (s.preview && s.preview->sequence() != sent_preview_seq_) {
        const auto now = std::chrono::steady_clock::now();
        send_preview = sent_preview_seq_ == 0 ||
                       std::chrono::duration<double>(now - last_preview_).count() >= interval_;
        if (send_preview) last_preview_ = now;
      }
      if (!job_changed && !send_preview && !include_events_) {
        busy_ = false;
        return;
      }
      send_job = job_changed || send_preview;
    }
    // Built outside the lock: reading the store and listing files must not
    // hold up the hub.
    v1::WatchJobResponse next;
    if (include_events_) ReadNewEvents(next);
    if (!send_job && next.events().empty()) {
      std::lock_guard<std::mutex> lock(mu_);
      if (cancelled_) return FinishLocked(grpc::Status::CANCELLED);
      busy_ = false;
      return KickLocked();  // a snapshot may have come meanwhile
    }
    *next.mutable_job() = *s.job;
    AddResultFiles(results_, *next.mutable_job());
    if (send_preview) *next.mutable_preview() = *s.preview;

    std::lock_guard<std::mutex> lock(mu_);
    if (cancelled_) return FinishLocked(grpc::Status::CANCELLED);
    resp_ = std::move(next);
    if (send_preview) sent_preview_seq_ = s.preview->sequence();
    sent_job_ = true;
    sent_state_ = s.job->state();
    sent_done_ = s.job->progress().done();
    sent_attempts_ = s.job->attempts();
    sent_terminal_ = IsTerminal(s.job->state());
    StartWrite(&resp_);  // keeps the turn until OnWriteDone
  }

  // Executor, holding the turn: the events recorded after the last one
  // sent (the log keeps at most kMaxEventsPerJob, so a few pages at most).
  // A failed read sends none now; the next message tries again.
  void ReadNewEvents(v1::WatchJobResponse& next) {
    for (int page = 0; page < 4; ++page) {
      auto got = store_->ListEvents(job_id_, sent_event_seq_, 500);
      if (!got.ok()) return;
      for (const JobEvent& e : got->events) {
        *next.add_events() = ToProto(e);
        sent_event_seq_ = std::max(sent_event_seq_, e.seq);
      }
      if (got->next_after == 0) return;
    }
  }

  void FinishLocked(const grpc::Status& s) {
    if (finished_) return;
    finished_ = true;
    Finish(s);
  }

  Principal caller_;
  JobHub* hub_;
  JobStore* store_;
  ResultStore* results_;
  BlockingExecutor* blocking_;
  std::string job_id_;
  uint32_t resolution_;
  double interval_;
  const bool include_events_;
  int64_t sent_event_seq_;  // only the turn's holder touches it
  uint64_t subscription_ = 0;
  bool subscribed_ = false;
  std::mutex mu_;
  JobSnapshot latest_;
  v1::WatchJobResponse resp_;
  bool busy_ = false;     // the turn is taken
  bool pending_ = false;  // latest_ has news for the client
  bool cancelled_ = false;
  bool finished_ = false;
  bool sent_job_ = false;
  bool sent_terminal_ = false;
  v1::JobState sent_state_ = v1::JOB_STATE_UNSPECIFIED;
  uint64_t sent_done_ = 0;
  uint32_t sent_attempts_ = 0;
  uint64_t sent_preview_seq_ = 0;
  std::chrono::steady_clock::time_point last_preview_;
};

// Streams a result file in chunks from the requested offset. The lookup and
// every chunk read run on the blocking executor; gRPC threads only write.
// The next chunk is read while the previous one is on the wire: at most one
// read and one write are outstanding, and the reactor finishes only when no
// read is (a read still running must not outlive the reactor). Two chunk
// buffers take turns, so a download allocates and zero-fills them once.
class FetchReactor : public grpc::ServerWriteReactor<v1::FetchResultResponse> {
 public:
  FetchReactor(JobStore* store, ResultStore* results, BlockingExecutor* blocking,
               const v1::FetchResultRequest& req, Principal caller, int64_t retention_ms)
      : caller_(std::move(caller)),
        retention_ms_(retention_ms),
        store_(store),
        results_(results),
        blocking_(blocking),
        job_id_(req.job_id()),
        file_name_(req.file_name()),
        offset_(req.offset()) {
    reading_ = true;
    if (!blocking_->Post([this] { Start(); })) Finish(Busy(*blocking_));
  }
  void OnWriteDone(bool ok) override {
    std::optional<Chunk> next;
    {
      std::lock_guard<std::mutex> lock(mu_);
      writing_ = false;
      if (!ok) {
        failed_ = true;
        if (reading_) return;  // the read's end finishes the call
      } else if (ahead_) {
        next = std::move(ahead_);
        ahead_.reset();
        writing_ = true;
      } else {
        return;  // the read in flight sends when it is done
      }
    }
    if (!ok) return Finish(grpc::Status::CANCELLED);
    Send(std::move(*next));
  }
  void OnDone() override { delete this; }

 private:
  // A chunk read from the store; `end` past the last byte.
  struct Chunk {
    absl::Status status;
    std::string data;
    uint64_t offset = 0;
    bool end = false;
  };

  void Start() {
    if (grpc::Status s = Open(); !s.ok()) {
      {
        std::lock_guard<std::mutex> lock(mu_);
        reading_ = false;
      }
      return Finish(s);
    }
    read_offset_ = offset_;
    ReadNext();
  }

  Chunk ReadChunk() {
    Chunk c;
    c.offset = read_offset_;
    if (read_offset_ >= size_) {
      c.end = true;
      return c;
    }
    std::string buffer;
    {
      std::lock_guard<std::mutex> lock(mu_);
      buffer.swap(spare_);
    }
    auto data = file_name_.empty() ? results_->Read(key_, read_offset_, kFetchChunk,
                                                    std::move(buffer))
                                   : results_->ReadFile(key_, file_name_, running_, read_offset_,
                                                        kFetchChunk, std::move(buffer));
    if (!data.ok()) {
      c.status = data.status();
    } else if (data->empty()) {
      c.status = absl::DataLossError(
          absl::StrCat("result ends at ", read_offset_, " of ", size_, " bytes"));
    } else {
      read_offset_ += data->size();
      c.data = std::move(*data);
    }
    return c;
  }

  // Executor: reads a chunk and sends it, or leaves it for OnWriteDone
  // while the previous chunk is still being written.
  void ReadNext() {
    Chunk c = ReadChunk();
    bool failed;
    {
      std::lock_guard<std::mutex> lock(mu_);
      reading_ = false;
      failed = failed_;
      if (!failed && writing_) {
        ahead_ = std::move(c);
        return;
      }
      writing_ = !failed;
    }
    if (failed) return Finish(grpc::Status::CANCELLED);  // the client went away
    Send(std::move(c));
  }

  // Owns resp_ (no write outstanding) and no read is running.
  void Send(Chunk c) {
    if (!c.status.ok()) return Finish(ToGrpc(c.status));
    if (c.end && sent_any_) return Finish(grpc::Status::OK);
    if (sent_any_) {
      std::lock_guard<std::mutex> lock(mu_);
      spare_.swap(*resp_.mutable_data());  // the written chunk's buffer, for the next read
      resp_.Clear();  // size and hash ride on the first chunk only
    }
    resp_.set_offset(c.offset);
    resp_.set_data(std::move(c.data));
    sent_any_ = true;
    {
      std::lock_guard<std::mutex> lock(mu_);
      if (c.end)
        ahead_ = Chunk{absl::OkStatus(), "", c.offset, true};  // an empty file's one chunk
      else
        reading_ = true;
    }
    if (!c.end && !blocking_->Post([this] { ReadNext(); })) {
      std::lock_guard<std::mutex> lock(mu_);
      reading_ = false;
      ahead_ = Chunk{absl::ResourceExhaustedError(Busy(*blocking_).error_message()), "", 0, false};
    }
    StartWrite(&resp_);
  }

  // Finds the file and checks the request against it.
  grpc::Status Open() {
    auto rec = LoadVisibleJob(*store_, caller_, job_id_);
    if (!rec.ok()) return ToGrpc(rec.status());
    if (rec->result_expire_time != 0) return ToGrpc(ResultExpiredError(*rec, retention_ms_));
    // Further files (book pages) of a running job can be fetched as soon as
    // they are listed; everything else waits for success.
    running_ = rec->state == JobState::kRunning;
    if (rec->state != JobState::kSucceeded && !(running_ && !file_name_.empty()))
      return ToGrpc(ResultNotReadyError(*rec));
    size_ = rec->result_size;
    std::string sha256 = rec->result_sha256;
    // Committed further files live under the job id (the result key).
    key_ = file_name_.empty() ? rec->result_key : rec->id;
    if (!file_name_.empty()) {
      bool found = false;
      for (const StoredFile& f : results_->ListFiles(rec->id, running_))
        if (f.name == file_name_) {
          size_ = f.size;
          sha256 = f.sha256;
          found = true;
        }
      if (!found)
        return grpc::Status(
            grpc::StatusCode::NOT_FOUND,
            absl::StrCat("job ", rec->id, " has no result file '", EchoId(file_name_), "'"));
    }
    if (offset_ > size_)
      return grpc::Status(
          grpc::StatusCode::OUT_OF_RANGE,
          absl::StrCat("offset ", offset_, " is past the end (", size_, " bytes)"));
    resp_.set_total_size(size_);
    resp_.set_sha256(std::move(sha256));
    return grpc::Status::OK;
  }

  Principal caller_;
  int64_t retention_ms_;
  JobStore* store_;
  ResultStore* results_;
  BlockingExecutor* blocking_;
  std::string job_id_;
  std::string file_name_;
  std::string key_;
  bool running_ = false;
  uint64_t offset_;
  uint64_t read_offset_ = 0;  // the next chunk to read
  uint64_t size_ = 0;
  bool sent_any_ = false;
  v1::FetchResultResponse resp_;
  std::mutex mu_;
  bool reading_ = false, writing_ = false, failed_ = false;
  std::optional<Chunk> ahead_;
  std::string spare_;  // a chunk buffer no one uses, for the next read
};

}  // namespace

grpc::Status ToGrpc(const absl::Status& s) {
  if (s.ok()) return grpc::Status::OK;
  return grpc::Status(static_cast<grpc::StatusCode>(s.code()), std::string(s.message()));
}

NimbusServiceImpl::NimbusServiceImpl(JobStore* store, ResultStore* results, AssetStore* assets,
                                     JobHub* hub, WorkerPool* pool, spec::Limits limits)
    : store_(store),
      results_(results),
      assets_(assets),
      hub_(hub),
      pool_(pool),
      limits_(std::move(limits)) {}

namespace {
// Submissions at least this large are followed by malloc_trim.
constexpr size_t kTrimAfterRequestBytes = size_t{1} << 20;
}  // namespace

grpc::ServerUnaryReactor* NimbusServiceImpl::SubmitJob(grpc::CallbackServerContext* ctx,
                                                       const v1::SubmitJobRequest* req,
                                                       v1::SubmitJobResponse* resp) {
  // The reactor is answered from the admission thread; gRPC keeps `req`
  // and `resp` alive until then.
  grpc::ServerUnaryReactor* reactor = ctx->DefaultReactor();
  auto caller = Authenticate(tokens_, *ctx);
  if (!caller.ok()) {
    reactor->Finish(ToGrpc(caller.status()));
    return reactor;
  }
  if (!admission_.Post([this, req, resp, reactor, p = *caller] {
        const bool large = req->ByteSizeLong() > kTrimAfterRequestBytes;
        reactor->Finish(Admit(p, *req, *resp));
        // The copies a large request made are freed by now: hand their
        // pages back instead of keeping them for reuse (heap_tuning.h).
        if (large) ::malloc_trim(0);
      }))
    reactor->Finish(
        grpc::Status(grpc::StatusCode::RESOURCE_EXHAUSTED,
                     absl::StrCat("server busy: ", admission_.max_pending(),
                                  " submissions are waiting to be validated; retry shortly")));
  return reactor;
}

namespace {

// Strings a submission stores: bounded before any work, so a 10 MB name is
// never logged, stored or listed.
grpc::Status CheckSubmittedText(const v1::SubmitJobRequest& req) {
  const auto too_long = [](const char* field, size_t size, size_t max) {
    return grpc::Status(grpc::StatusCode::INVALID_ARGUMENT,
                        absl::StrCat(field, ": must be at most ", max, " bytes, got ", size));
  };
  if (req.spec().name().size() > kMaxJobNameBytes)
    return too_long("name", req.spec().name().size(), kMaxJobNameBytes);
  if (req.request_id().size() > kMaxJobNameBytes)
    return too_long("request_id", req.request_id().size(), kMaxJobNameBytes);
  return grpc::Status::OK;
}

}  // namespace

grpc::Status NimbusServiceImpl::Admit(const Principal& caller, const v1::SubmitJobRequest& req,
                                      v1::SubmitJobResponse& resp, const JobRecord* retry_of) {
  if (grpc::Status st = CheckSubmittedText(req); !st.ok()) return st;
  const int priority = req.has_priority() ? req.priority() : kDefaultPriority;
  if (auto st = CheckPriority(priority); !st.ok()) return ToGrpc(st);
  // Its size, unknown fields and list lengths, before anything copies it.
  if (auto st = spec::CheckSpecShape(req.spec(), limits_); !st.ok()) return ToGrpc(st);
  if (auto st = CheckJobQuotas(*store_, caller, quotas_); !st.ok()) return ToGrpc(st);
  if (assets_ != nullptr)
    if (auto st = CheckAssetOwnership(req.spec(), caller, *assets_); !st.ok()) return ToGrpc(st);
  // The free-space reserve: refuse new work before the disk fills.
  if (auto st = results_->CheckFreeSpace(); !st.ok()) return ToGrpc(st);
  // Meshes and grids are read whole by a sandboxed child before the
  // converter parses any of them in this process (server/untrusted_file.h);
  // an asset named by path is refused there first, before any file is read.
  if (auto st = CheckSpecAssets(req.spec(), limits_.asset_dir, limits_.allow_local_paths); !st.ok())
    return ToGrpc(st);
  // Validation names the offending field; nothing is allocated for grids.
  auto job = spec::ConvertSpec(req.spec(), limits_);
  if (!job.ok()) return ToGrpc(job.status());
  NewJob nj;
  nj.id = NewJobId();
  nj.name = job->name;
  req.spec().SerializeToString(&nj.spec);
  nj.request_id = req.request_id();
  nj.progress_total = job->work.total;
  for (const auto& w : job->warnings) nj.warnings += w + "\n";
  nj.owner = caller.name;
  nj.priority = priority;
  if (retry_of != nullptr) nj.retried_from = retry_of->id;
  if (job->result_cacheable()) nj.spec_sha256 = spec::SpecHash(req.spec());
  // A finished twin answers at once, without memory admission.
  // A retry is asked for to run again: never a cache hit.
  const bool cached = retry_of == nullptr && !req.spec().no_cache() && !nj.spec_sha256.empty() &&
                      AnswerFromCache(nj);
  if (!cached) {
    // Memory admission: the job's one pilot census, if it needs one.
    auto memory = AdmitMemory(*job, limits_, pool_->threads_per_job());
    if (!memory.ok()) return ToGrpc(memory.status());
    nj.estimated_memory_bytes = memory->estimated_bytes;
    nj.shard_count = req.spec().shards() > 0 ? req.spec().shards()
                                             : AutoShards(*job, auto_shard_iterations_);
  }
  nj.submitted_by = caller.name;  // Create logs the submission with the job
  auto rec = store_->Create(nj, NowMs());
  // Not stored, or an idempotent retry got its first job: the cache's copy
  // is not needed.
  if (cached && (!rec.ok() || rec->id != nj.id)) (void)results_->Delete(nj.id);
  if (!rec.ok()) return ToGrpc(rec.status());
  spdlog::info("job={} event=submitted name={} owner={} work={} priority={}{}", rec->id, rec->name,
               rec->owner, rec->progress_total, rec->priority,
               rec->retried_from.empty() ? "" : " retried_from=" + rec->retried_from);
  *resp.mutable_job() = ToProto(*rec, true);
  if (rec->state == JobState::kQueued) hub_->PublishJob(resp.job());
  pool_->Wake();
  return grpc::Status::OK;
}

bool NimbusServiceImpl::AnswerFromCache(NewJob& nj) {
  auto hit = store_->FindCached(nj.spec_sha256, nj.owner);
  if (!hit.ok() || !hit->has_value()) return false;
  const JobRecord& from = **hit;
  // Its own copy: each job's result lives and expires on its own.
  auto copy = results_->CopyResult(from.result_key, from.id, nj.id);
  if (!copy.ok()) {
    spdlog::warn("job={} event=cache_copy_failed from={} reason=\"{}\"", nj.id, from.id,
                 copy.status().ToString());
    return false;
  }
  nj.cached_from = from.id;
  nj.cached_result.result_key = copy->key;
  nj.cached_result.result_size = copy->size;
  nj.cached_result.result_sha256 = copy->sha256;
  nj.estimated_memory_bytes = from.estimated_memory_bytes;
  spdlog::info("job={} event=cache_hit from={}", nj.id, from.id);
  return true;
}

void NimbusServiceImpl::AddShardProgress(const JobRecord& rec, v1::Job& view) {
  if (rec.shard_count <= 1 || !rec.parent_id.empty() || rec.state != JobState::kQueued) return;
  if (auto shards = store_->ListShards(rec.id); shards.ok()) AggregateShards(*shards, view);
}

grpc::ServerUnaryReactor* NimbusServiceImpl::OffThread(
    grpc::CallbackServerContext* ctx, std::function<grpc::Status(const Principal&)> work) {
  // gRPC keeps the request and response alive until the reactor finishes.
  grpc::ServerUnaryReactor* reactor = ctx->DefaultReactor();
  auto caller = Authenticate(tokens_, *ctx);
  if (!caller.ok()) {
    reactor->Finish(ToGrpc(caller.status()));
    return reactor;
  }
  if (!blocking_.Post([reactor, work = std::move(work), p = *caller] { reactor->Finish(work(p)); }))
    reactor->Finish(Busy(blocking_));
  return reactor;
}

grpc::ServerUnaryReactor* NimbusServiceImpl::GetJob(grpc::CallbackServerContext* ctx,
                                                    const v1::GetJobRequest* req,
                                                    v1::GetJobResponse* resp) {
  return OffThread(ctx, [this, req, resp](const Principal& caller) {
    auto rec = LoadVisibleJob(*store_, caller, req->job_id());
    if (!rec.ok()) return ToGrpc(rec.status());
    *resp->mutable_job() = ToProto(*rec, true);
    AddShardProgress(*rec, *resp->mutable_job());
    // The hub has fresher progress than the store's last heartbeat.
    if (auto live = hub_->Latest(req->job_id()); live && live->state() == resp->job().state()) {
      *resp->mutable_job()->mutable_progress() = live->progress();
      *resp->mutable_job()->mutable_stats() = live->stats();
    }
    AddResultFiles(results_, *resp->mutable_job());
    return grpc::Status::OK;
  });
}

grpc::ServerUnaryReactor* NimbusServiceImpl::ListJobs(grpc::CallbackServerContext* ctx,
                                                      const v1::ListJobsRequest* req,
                                                      v1::ListJobsResponse* resp) {
  return OffThread(ctx, [this, req, resp](const Principal& caller) {
    if (!v1::JobState_IsValid(req->state()))
      return grpc::Status(grpc::StatusCode::INVALID_ARGUMENT,
                          absl::StrCat("state: unknown value ", int(req->state())));
    ListOptions o;
    o.page_size = req->page_size() <= 0 ? 50 : std::min(req->page_size(), 500);
    o.page_token = req->page_token();
    // Well below gRPC's 4 MiB default, whatever the jobs hold.
    o.max_bytes = uint64_t{1} << 20;
    if (req->state() != v1::JOB_STATE_UNSPECIFIED) o.state = FromProto(req->state());
    if (!caller.admin) o.owner = caller.name;
    auto page = store_->List(o);
    if (!page.ok()) return ToGrpc(page.status());
    for (const JobRecord& r : page->jobs) {
      v1::Job* j = resp->add_jobs();
      *j = ToProto(r, false);
      AddShardProgress(r, *j);
    }
    resp->set_next_page_token(page->next_page_token);
    return grpc::Status::OK;
  });
}

grpc::ServerUnaryReactor* NimbusServiceImpl::PokeJob(grpc::CallbackServerContext* ctx,
                                                     const v1::PokeJobRequest* req,
                                                     v1::PokeJobResponse* resp) {
  return OffThread(ctx, [this, req, resp](const Principal& caller) {
    return Poke(caller, *req, *resp);
  });
}

grpc::Status NimbusServiceImpl::Poke(const Principal& caller, const v1::PokeJobRequest& req,
                                     v1::PokeJobResponse& resp) {
  if (req.job_id().empty())
    return grpc::Status(grpc::StatusCode::INVALID_ARGUMENT, "job_id: required");
  // Another principal's job is NOT_FOUND, as for every other call.
  auto rec = LoadVisibleJob(*store_, caller, req.job_id());
  if (!rec.ok()) return ToGrpc(rec.status());
  v1::JobSpec spec;
  if (!spec.ParseFromString(rec->spec) || !spec.has_jelly())
    return grpc::Status(
        grpc::StatusCode::FAILED_PRECONDITION,
        absl::StrCat("job ", rec->id, " is not a jelly job; only jelly bodies can be poked"));
  if (rec->state != JobState::kRunning)
    return grpc::Status(grpc::StatusCode::FAILED_PRECONDITION,
                        absl::StrCat("job ", rec->id, " is ", v1::JobState_Name(ToProto(rec->state)),
                                     "; pokes act on running jobs only"));
  // The same checks as a spec's impulses.
  auto push = spec::ConvertJellyPush(req.push(), spec.jelly().bodies_size(), "push");
  if (!push.ok()) return ToGrpc(push.status());
  PokeRecord poke;
  poke.body = push->body;
  poke.drag = push->kind == JellyPoke::Kind::kDrag;
  poke.x = push->vector.x, poke.y = push->vector.y, poke.z = push->vector.z;
  poke.drag_stiffness = push->stiffness;
  poke.drag_frames = push->frames;
  // Frames done when the poke arrives: the hub's progress is fresher than
  // the store's last heartbeat.
  uint64_t done = rec->progress_done;
  if (auto live = hub_->Latest(rec->id); live && live->state() == v1::JOB_STATE_RUNNING) {
    // Writing the result: every frame is simulated, no poke could act.
    if (live->progress().phase() == v1::PROGRESS_PHASE_WRITING)
      return grpc::Status(grpc::StatusCode::FAILED_PRECONDITION,
                          absl::StrCat("job ", rec->id, " has simulated all its frames"));
    done = std::max<uint64_t>(done, live->progress().done());
  }
  auto added = store_->AddPoke(rec->id, poke);
  if (!added.ok()) return ToGrpc(added.status());
  spdlog::info("job={} event=poke body={} drag={} earliest_frame={}", rec->id, poke.body,
               poke.drag, done);
  *resp.mutable_job() = ToProto(*rec, false);
  resp.set_poke_id(added->seq);
  resp.set_earliest_frame(done);
  return grpc::Status::OK;
}

grpc::ServerUnaryReactor* NimbusServiceImpl::CancelJob(grpc::CallbackServerContext* ctx,
                                                       const v1::CancelJobRequest* req,
                                                       v1::CancelJobResponse* resp) {
  return OffThread(ctx, [this, req, resp](const Principal& caller) {
    return Cancel(caller, req->job_id(), *resp->mutable_job());
  });
}

grpc::Status NimbusServiceImpl::Cancel(const Principal& caller, const std::string& job_id,
                                       v1::Job& out) {
  // Owners never change, so the check holds for the cancel that follows.
  auto visible = LoadVisibleJob(*store_, caller, job_id);
  if (!visible.ok()) return ToGrpc(visible.status());
  // Logged first, so a worker that sees the request at its next heartbeat
  // cannot log the job's end before it.
  LogJobEvent(*store_, job_id, "cancel_requested", {{"by", caller.name}});
  // A queued job ends here, with no worker to log its end: the store logs
  // it with the change.
  auto rec = store_->RequestCancel(job_id, NowMs(), caller.name);
  if (!rec.ok()) return ToGrpc(rec.status());
  pool_->Cancel(job_id);
  // A sharded job's cancel reaches the shards this process runs at once.
  if (rec->parent_id.empty())
    for (uint32_t k = 0; rec->shard_count > 1 && k < rec->shard_count; ++k)
      pool_->Cancel(ShardJobId(job_id, k));
  spdlog::info("job={} event=cancel_requested state={}", rec->id,
               v1::JobState_Name(ToProto(rec->state)));
  out = ToProto(*rec, false);
  if (rec->state == JobState::kCancelled) {
    // Watchers of a queued job learn of its end here; no worker will tell them.
    hub_->PublishJob(out);
    hub_->Forget(job_id);
  }
  if (rec->state != JobState::kRunning) return grpc::Status::OK;
  // A job this process runs publishes its end to our hub; one another
  // replica runs reaches it through the shared store's feed once that
  // worker sees the cancel at its next heartbeat.
  auto live = hub_->Latest(job_id);
  if (live && live->state() != v1::JOB_STATE_RUNNING) {
    out = *live;  // it stopped already: answer with its end, not the stale RUNNING
    return grpc::Status::OK;
  }
  if (auto stopped = AwaitStop(job_id)) out = *stopped;
  return grpc::Status::OK;
}

std::shared_ptr<const v1::Job> NimbusServiceImpl::AwaitStop(const std::string& job_id) {
  if (cancel_wait_ms_ <= 0) return nullptr;
  // Waiting holds an executor thread; keep one free for everything else.
  if (cancel_waits_.fetch_add(1) >= blocking_.threads() - 1) {
    cancel_waits_.fetch_sub(1);
    return nullptr;
  }
  struct Waiter {
    std::mutex mu;
    std::condition_variable cv;
    std::shared_ptr<const v1::Job> stopped;
  };
  auto w = std::make_shared<Waiter>();
  auto stop = [w](std::shared_ptr<const v1::Job> job) {
    std::lock_guard<std::mutex> lock(w->mu);
    if (!w->stopped) w->stopped = std::move(job);
    w->cv.notify_all();
  };
  // Any state but RUNNING ends the wait: CANCELLED normally, or whatever the
  // job reached first (succeeded, failed, or released at shutdown).
  const uint64_t sub = hub_->Subscribe(job_id, 0, 0, [stop](const JobSnapshot& s) {
    if (s.job && s.job->state() != v1::JOB_STATE_RUNNING) stop(s.job);
  });
  // Its worker writes the store before publishing, so a job that ended
  // before we subscribed shows here.
  if (auto rec = store_->Get(job_id); rec.ok() && rec->state != JobState::kRunning)
    stop(std::make_shared<v1::Job>(ToProto(*rec, false)));
  std::shared_ptr<const v1::Job> stopped;
  {
    std::unique_lock<std::mutex> lock(w->mu);
    w->cv.wait_for(lock, std::chrono::milliseconds(cancel_wait_ms_),
                   [&] { return w->stopped != nullptr; });
    stopped = w->stopped;
  }
  hub_->Unsubscribe(job_id, sub);
  cancel_waits_.fetch_sub(1);
  return stopped;
}

grpc::ServerWriteReactor<v1::WatchJobResponse>* NimbusServiceImpl::WatchJob(
    grpc::CallbackServerContext* ctx, const v1::WatchJobRequest* req) {
  auto caller = Authenticate(tokens_, *ctx);
  if (!caller.ok())
    return new Refused<grpc::ServerWriteReactor<v1::WatchJobResponse>>(ToGrpc(caller.status()));
  return new WatchReactor(hub_, store_, results_, &blocking_, *req, *caller);
}

grpc::ServerWriteReactor<v1::FetchResultResponse>* NimbusServiceImpl::FetchResult(
    grpc::CallbackServerContext* ctx, const v1::FetchResultRequest* req) {
  auto caller = Authenticate(tokens_, *ctx);
  if (!caller.ok())
    return new Refused<grpc::ServerWriteReactor<v1::FetchResultResponse>>(ToGrpc(caller.status()));
  return new FetchReactor(store_, results_, &blocking_, *req, *caller, retention_ms_);
}

namespace {

// Receives one asset upload. The first message announces hash, size and
// name; bytes are hashed while they arrive and the file is stored only when
// both match at the end of the stream. Each message is written to disk on
// the blocking executor; the next read starts from there.
class UploadReactor : public grpc::ServerReadReactor<v1::UploadAssetRequest> {
 public:
  UploadReactor(AssetStore* assets, BlockingExecutor* blocking, v1::UploadAssetResponse* resp,
                Principal caller, Quotas quotas)
      : caller_(std::move(caller)),
        quotas_(quotas),
        assets_(assets),
        blocking_(blocking),
        resp_(resp) {
    StartRead(&req_);
  }

  void OnReadDone(bool ok) override {
    if (!blocking_->Post([this, ok] { Handle(ok); })) Finish(Busy(*blocking_));
  }

  void OnCancel() override {}
  void OnDone() override { delete this; }

 private:
  void Handle(bool ok) {
    if (!ok) {
      // The client closed its side: the upload is complete or truncated.
      if (!upload_)
        return Finish(grpc::Status(grpc::StatusCode::INVALID_ARGUMENT,
                                   "empty upload: the first message must name "
                                   "sha256, size_bytes and file_name"));
      auto info = upload_->Finish();
      if (!info.ok()) {
        spdlog::warn("event=upload_rejected sha256={} reason=\"{}\"", sha256_,
                     std::string(info.status().message()));
        return Finish(ToGrpc(info.status()));
      }
      resp_->set_sha256(info->sha256);
      resp_->set_size_bytes(info->size);
      resp_->set_already_present(info->already_present);
      spdlog::info("event=asset_stored sha256={} size={} new={}", info->sha256, info->size,
                   !info->already_present);
      return Finish(grpc::Status::OK);
    }
    if (!upload_) {
      sha256_ = req_.sha256();
      if (auto st = CheckAssetQuota(*assets_, caller_, quotas_, sha256_, req_.size_bytes());
          !st.ok())
        return Finish(ToGrpc(st));
      auto u = assets_->Begin(req_.sha256(), req_.size_bytes(), req_.file_name(), caller_.name);
      if (!u.ok()) return Finish(ToGrpc(u.status()));
      upload_ = std::move(*u);
    } else if (!req_.sha256().empty() && req_.sha256() != sha256_) {
      return Finish(grpc::Status(grpc::StatusCode::INVALID_ARGUMENT,
                                 "sha256 changed in the middle of an upload"));
    }
    if (auto st = upload_->Append(req_.data()); !st.ok()) return Finish(ToGrpc(st));
    req_.Clear();
    StartRead(&req_);
  }

  Principal caller_;
  Quotas quotas_;
  AssetStore* assets_;
  BlockingExecutor* blocking_;
  v1::UploadAssetResponse* resp_;
  v1::UploadAssetRequest req_;
  std::string sha256_;
  std::unique_ptr<AssetStore::Upload> upload_;
};

}  // namespace

grpc::ServerReadReactor<v1::UploadAssetRequest>* NimbusServiceImpl::UploadAsset(
    grpc::CallbackServerContext* ctx, v1::UploadAssetResponse* resp) {
  using Reader = grpc::ServerReadReactor<v1::UploadAssetRequest>;
  if (!assets_)
    return new Refused<Reader>(grpc::Status(grpc::StatusCode::UNIMPLEMENTED, "no asset store"));
  auto caller = Authenticate(tokens_, *ctx);
  if (!caller.ok()) return new Refused<Reader>(ToGrpc(caller.status()));
  return new UploadReactor(assets_, &blocking_, resp, *caller, quotas_);
}

grpc::ServerUnaryReactor* NimbusServiceImpl::PinJob(grpc::CallbackServerContext* ctx,
                                                    const v1::PinJobRequest* req,
                                                    v1::PinJobResponse* resp) {
  return OffThread(ctx, [this, req, resp](const Principal& caller) {
    if (auto visible = LoadVisibleJob(*store_, caller, req->job_id()); !visible.ok())
      return ToGrpc(visible.status());
    auto rec = store_->SetPinned(req->job_id(), req->pinned());
    if (!rec.ok()) return ToGrpc(rec.status());
    LogJobEvent(*store_, rec->id, req->pinned() ? "pinned" : "unpinned", {{"by", caller.name}});
    spdlog::info("job={} event={}", rec->id, req->pinned() ? "pinned" : "unpinned");
    *resp->mutable_job() = ToProto(*rec, false);
    return grpc::Status::OK;
  });
}

grpc::ServerUnaryReactor* NimbusServiceImpl::DeleteJob(grpc::CallbackServerContext* ctx,
                                                       const v1::DeleteJobRequest* req,
                                                       v1::DeleteJobResponse* resp) {
  return OffThread(ctx, [this, req, resp](const Principal& caller) {
    return Delete(caller, req->job_id(), *resp);
  });
}

grpc::Status NimbusServiceImpl::Delete(const Principal& caller, const std::string& job_id,
                                       v1::DeleteJobResponse& resp) {
  auto rec = LoadVisibleJob(*store_, caller, job_id);
  if (!rec.ok()) return ToGrpc(rec.status());
  if (!rec->parent_id.empty())
    return grpc::Status(grpc::StatusCode::FAILED_PRECONDITION,
                        absl::StrCat("job ", rec->id, " is a shard; delete its job ",
                                     rec->parent_id, " instead"));
  if (!IsTerminal(rec->state))
    return grpc::Status(
        grpc::StatusCode::FAILED_PRECONDITION,
        absl::StrCat("job ", rec->id, " is ", v1::JobState_Name(ToProto(rec->state)),
                     "; cancel it before deleting it"));
  // Files first: should the record outlive them, fetching says they are
  // missing; files outliving their record would never be found again.
  if (!rec->result_key.empty()) {
    auto freed = results_->Delete(rec->result_key);
    if (!freed.ok()) return ToGrpc(freed.status());
    resp.set_freed_bytes(*freed);
  }
  // Partials a failed or cancelled sharded job left behind.
  if (rec->shard_count > 1 && rec->parent_id.empty())
    if (auto shards = store_->ListShards(job_id); shards.ok())
      for (const JobRecord& s : *shards)
        if (!s.result_key.empty()) (void)results_->Delete(s.result_key);
  if (auto st = store_->Delete(job_id); !st.ok()) return ToGrpc(st);
  hub_->Forget(job_id);
  spdlog::info("job={} event=deleted freed_bytes={}", job_id, resp.freed_bytes());
  return grpc::Status::OK;
}

grpc::ServerUnaryReactor* NimbusServiceImpl::SetJobPriority(grpc::CallbackServerContext* ctx,
                                                            const v1::SetJobPriorityRequest* req,
                                                            v1::SetJobPriorityResponse* resp) {
  return OffThread(ctx, [this, req, resp](const Principal& caller) {
    if (auto st = CheckPriority(req->priority()); !st.ok()) return ToGrpc(st);
    auto visible = LoadVisibleJob(*store_, caller, req->job_id());
    if (!visible.ok()) return ToGrpc(visible.status());
    if (!visible->parent_id.empty())
      return grpc::Status(
          grpc::StatusCode::FAILED_PRECONDITION,
          absl::StrCat("job ", visible->id, " is a shard; set the priority of its job ",
                       visible->parent_id, " instead"));
    auto rec = store_->SetPriority(req->job_id(), req->priority());
    if (!rec.ok()) return ToGrpc(rec.status());
    spdlog::info("job={} event=priority priority={} by={}", rec->id, rec->priority, caller.name);
    LogJobEvent(*store_, rec->id, "priority",
                {{"by", caller.name}, {"priority", absl::StrCat(rec->priority)}});
    *resp->mutable_job() = ToProto(*rec, false);
    hub_->PublishJob(resp->job());
    return grpc::Status::OK;
  });
}

grpc::ServerUnaryReactor* NimbusServiceImpl::RetryJob(grpc::CallbackServerContext* ctx,
                                                      const v1::RetryJobRequest* req,
                                                      v1::RetryJobResponse* resp) {
  return OffThread(ctx, [this, req, resp](const Principal& caller) {
    return Retry(caller, req->job_id(), *resp);
  });
}

grpc::Status NimbusServiceImpl::Retry(const Principal& caller, const std::string& job_id,
                                      v1::RetryJobResponse& resp) {
  auto rec = LoadVisibleJob(*store_, caller, job_id);
  if (!rec.ok()) return ToGrpc(rec.status());
  if (!rec->parent_id.empty())
    return grpc::Status(
        grpc::StatusCode::FAILED_PRECONDITION,
        absl::StrCat("job ", rec->id, " is a shard; retry its job ", rec->parent_id, " instead"));
  if (rec->state != JobState::kFailed && rec->state != JobState::kCancelled)
    return grpc::Status(
        grpc::StatusCode::FAILED_PRECONDITION,
        absl::StrCat("job ", rec->id, " is ", v1::JobState_Name(ToProto(rec->state)),
                     "; only a FAILED or CANCELLED job can be retried"));
  v1::SubmitJobRequest again;
  if (!again.mutable_spec()->ParseFromString(rec->spec))
    return grpc::Status(grpc::StatusCode::INTERNAL,
                        absl::StrCat("job ", rec->id, ": its stored spec does not parse"));
  again.set_priority(rec->priority);
  // The new job is the original owner's, whoever asks.
  const Principal owner{rec->owner, caller.admin};
  v1::SubmitJobResponse submitted;
  if (grpc::Status st = Admit(owner, again, submitted, &*rec); !st.ok()) return st;
  LogJobEvent(*store_, rec->id, "retried",
              {{"by", caller.name}, {"retried_as", submitted.job().id()}});
  *resp.mutable_job() = std::move(*submitted.mutable_job());
  return grpc::Status::OK;
}

grpc::ServerUnaryReactor* NimbusServiceImpl::ListWorkers(grpc::CallbackServerContext* ctx,
                                                         const v1::ListWorkersRequest* req,
                                                         v1::ListWorkersResponse* resp) {
  (void)req;
  return OffThread(ctx, [this, resp](const Principal&) {
    auto rows = store_->ListWorkers();
    if (!rows.ok()) return ToGrpc(rows.status());
    const TimeMs now = NowMs();
    for (const WorkerInfo& w : *rows) *resp->add_workers() = ToProto(w, now, lease_ms_);
    return grpc::Status::OK;
  });
}

grpc::ServerUnaryReactor* NimbusServiceImpl::GetJobEvents(grpc::CallbackServerContext* ctx,
                                                          const v1::GetJobEventsRequest* req,
                                                          v1::GetJobEventsResponse* resp) {
  return OffThread(ctx, [this, req, resp](const Principal& caller) {
    if (auto visible = LoadVisibleJob(*store_, caller, req->job_id()); !visible.ok())
      return ToGrpc(visible.status());
    if (req->page_size() < 0 || req->after_seq() < 0)
      return grpc::Status(grpc::StatusCode::INVALID_ARGUMENT,
                          req->page_size() < 0 ? "page_size: must not be negative"
                                               : "after_seq: must not be negative");
    auto page = store_->ListEvents(req->job_id(), req->after_seq(), req->page_size());
    if (!page.ok()) return ToGrpc(page.status());
    for (const JobEvent& e : page->events) *resp->add_events() = ToProto(e);
    resp->set_next_after_seq(page->next_after);
    resp->set_dropped(page->dropped);
    return grpc::Status::OK;
  });
}

}  // namespace nimbus::server
