#include "server/nimbus_service.h"

#include <spdlog/spdlog.h>

#include <chrono>
#include <random>

#include "absl/strings/str_cat.h"
#include "server/job_view.h"

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

grpc::ServerUnaryReactor* Done(grpc::CallbackServerContext* ctx, const grpc::Status& s) {
  auto* r = ctx->DefaultReactor();
  r->Finish(s);
  return r;
}

bool IsTerminal(v1::JobState s) {
  return s == v1::JOB_STATE_SUCCEEDED || s == v1::JOB_STATE_FAILED || s == v1::JOB_STATE_CANCELLED;
}

// Adds the result's further files (book pages) to a job view: the committed
// list once it succeeded, the pages finished so far while it runs.
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
class WatchReactor : public grpc::ServerWriteReactor<v1::WatchJobResponse> {
 public:
  WatchReactor(JobHub* hub, JobStore* store, ResultStore* results, const v1::WatchJobRequest& req,
               const v1::Job& initial)
      : hub_(hub),
        results_(results),
        job_id_(req.job_id()),
        interval_(req.preview_interval_seconds() > 0 ? req.preview_interval_seconds() : 1.0) {
    latest_.job = std::make_shared<v1::Job>(initial);
    latest_.version = 0;
    // The first write carries the store's record; hub snapshots follow.
    {
      std::lock_guard<std::mutex> lock(mu_);
      WriteLocked();
    }
    subscription_ = hub_->Subscribe(job_id_, req.preview_resolution(), interval_,
                                    [this](const JobSnapshot& s) { OnSnapshot(s); });
    // The job may have finished (and left the hub) between the first read
    // and the subscription: read the store once more so we never wait forever.
    if (auto rec = store->Get(job_id_); rec.ok() && IsTerminal(ToProto(rec->state))) {
      JobSnapshot s;
      s.job = std::make_shared<v1::Job>(ToProto(*rec, false));
      OnSnapshot(s);
    }
  }

  void OnWriteDone(bool ok) override {
    std::lock_guard<std::mutex> lock(mu_);
    writing_ = false;
    if (!ok) {
      FinishLocked(grpc::Status::OK);
      return;
    }
    if (sent_terminal_) {
      FinishLocked(grpc::Status::OK);
      return;
    }
    WriteLocked();
  }

  void OnCancel() override {
    std::lock_guard<std::mutex> lock(mu_);
    FinishLocked(grpc::Status::CANCELLED);
  }

  void OnDone() override {
    hub_->Unsubscribe(job_id_, subscription_);
    delete this;
  }

 private:
  void OnSnapshot(const JobSnapshot& s) {
    std::lock_guard<std::mutex> lock(mu_);
    if (!s.job || sent_terminal_) return;
    // Keep the preview we have when a snapshot without one arrives.
    auto preview = s.preview ? s.preview : latest_.preview;
    latest_ = s;
    latest_.preview = preview;
    if (!writing_ && !finished_) WriteLocked();
  }

  // Writes the newest state if it differs from what the client has.
  void WriteLocked() {
    if (writing_ || finished_) return;
    const v1::Job& job = *latest_.job;
    const bool job_changed = !sent_job_ || job.state() != sent_state_ ||
                             job.progress().done() != sent_done_ ||
                             job.attempts() != sent_attempts_;
    bool send_preview = false;
    if (latest_.preview && latest_.preview->sequence() != sent_preview_seq_) {
      const auto now = std::chrono::steady_clock::now();
      send_preview = sent_preview_seq_ == 0 ||
                     std::chrono::duration<double>(now - last_preview_).count() >= interval_;
      if (send_preview) last_preview_ = now;
    }
    if (!job_changed && !send_preview) return;
    resp_.Clear();
    *resp_.mutable_job() = job;
    AddResultFiles(results_, *resp_.mutable_job());
    if (send_preview) {
      *resp_.mutable_preview() = *latest_.preview;
      sent_preview_seq_ = latest_.preview->sequence();
    }
    sent_job_ = true;
    sent_state_ = job.state();
    sent_done_ = job.progress().done();
    sent_attempts_ = job.attempts();
    sent_terminal_ = IsTerminal(job.state());
    writing_ = true;
    StartWrite(&resp_);
  }

  void FinishLocked(const grpc::Status& s) {
    if (finished_) return;
    finished_ = true;
    Finish(s);
  }

  JobHub* hub_;
  ResultStore* results_;
  std::string job_id_;
  double interval_;
  uint64_t subscription_ = 0;
  std::mutex mu_;
  JobSnapshot latest_;
  v1::WatchJobResponse resp_;
  bool writing_ = false;
  bool finished_ = false;
  bool sent_job_ = false;
  bool sent_terminal_ = false;
  v1::JobState sent_state_ = v1::JOB_STATE_UNSPECIFIED;
  uint64_t sent_done_ = 0;
  uint32_t sent_attempts_ = 0;
  uint64_t sent_preview_seq_ = 0;
  std::chrono::steady_clock::time_point last_preview_;
};

// Streams a result file in chunks from the requested offset.
class FetchReactor : public grpc::ServerWriteReactor<v1::FetchResultResponse> {
 public:
  // `file_name` empty: the main file; otherwise one of the further files,
  // read from the running job's folder when `running`.
  FetchReactor(ResultStore* results, std::string key, std::string file_name, bool running,
               uint64_t offset, uint64_t size, std::string sha256)
      : results_(results),
        key_(std::move(key)),
        file_name_(std::move(file_name)),
        running_(running),
        offset_(offset),
        size_(size) {
    resp_.set_total_size(size_);
    resp_.set_sha256(std::move(sha256));
    Next();
  }
  void OnWriteDone(bool ok) override {
    if (!ok) return Finish(grpc::Status::CANCELLED);
    resp_.Clear();
    Next();
  }
  void OnDone() override { delete this; }

 private:
  void Next() {
    if (offset_ >= size_ && sent_any_) return Finish(grpc::Status::OK);
    auto data = file_name_.empty()
                    ? results_->Read(key_, offset_, kFetchChunk)
                    : results_->ReadFile(key_, file_name_, running_, offset_, kFetchChunk);
    if (!data.ok()) return Finish(ToGrpc(data.status()));
    resp_.set_offset(offset_);
    offset_ += data->size();
    resp_.set_data(std::move(*data));
    sent_any_ = true;
    StartWrite(&resp_);
  }

  ResultStore* results_;
  std::string key_;
  std::string file_name_;
  bool running_;
  uint64_t offset_;
  uint64_t size_;
  bool sent_any_ = false;
  v1::FetchResultResponse resp_;
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

grpc::ServerUnaryReactor* NimbusServiceImpl::SubmitJob(grpc::CallbackServerContext* ctx,
                                                       const v1::SubmitJobRequest* req,
                                                       v1::SubmitJobResponse* resp) {
  // The reactor is answered from the admission thread; gRPC keeps `req`
  // and `resp` alive until then.
  grpc::ServerUnaryReactor* reactor = ctx->DefaultReactor();
  if (!admission_.Post([this, req, resp, reactor] { reactor->Finish(Admit(*req, *resp)); }))
    reactor->Finish(
        grpc::Status(grpc::StatusCode::RESOURCE_EXHAUSTED,
                     absl::StrCat("server busy: ", admission_.max_pending(),
                                  " submissions are waiting to be validated; retry shortly")));
  return reactor;
}

grpc::Status NimbusServiceImpl::Admit(const v1::SubmitJobRequest& req,
                                      v1::SubmitJobResponse& resp) {
  // Validation names the offending field; nothing is allocated for grids.
  auto job = spec::ConvertSpec(req.spec(), limits_, pool_->threads_per_job());
  if (!job.ok()) return ToGrpc(job.status());
  NewJob nj;
  nj.id = NewJobId();
  nj.name = job->name;
  req.spec().SerializeToString(&nj.spec);
  nj.request_id = req.request_id();
  nj.progress_total = job->total_work;
  for (const auto& w : job->warnings) nj.warnings += w + "\n";
  nj.estimated_memory_bytes = job->estimated_memory_bytes;
  auto rec = store_->Create(nj, NowMs());
  if (!rec.ok()) return ToGrpc(rec.status());
  spdlog::info("job={} event=submitted name={} work={}", rec->id, rec->name, rec->progress_total);
  *resp.mutable_job() = ToProto(*rec, true);
  if (rec->state == JobState::kQueued) hub_->PublishJob(resp.job());
  pool_->Wake();
  return grpc::Status::OK;
}

grpc::ServerUnaryReactor* NimbusServiceImpl::GetJob(grpc::CallbackServerContext* ctx,
                                                    const v1::GetJobRequest* req,
                                                    v1::GetJobResponse* resp) {
  auto rec = store_->Get(req->job_id());
  if (!rec.ok()) return Done(ctx, ToGrpc(rec.status()));
  *resp->mutable_job() = ToProto(*rec, true);
  // The hub has fresher progress than the store's last heartbeat.
  if (auto live = hub_->Latest(req->job_id()); live && live->state() == resp->job().state()) {
    *resp->mutable_job()->mutable_progress() = live->progress();
    *resp->mutable_job()->mutable_stats() = live->stats();
  }
  AddResultFiles(results_, *resp->mutable_job());
  return Done(ctx, grpc::Status::OK);
}

grpc::ServerUnaryReactor* NimbusServiceImpl::ListJobs(grpc::CallbackServerContext* ctx,
                                                      const v1::ListJobsRequest* req,
                                                      v1::ListJobsResponse* resp) {
  ListOptions o;
  o.page_size = req->page_size() <= 0 ? 50 : std::min(req->page_size(), 500);
  o.page_token = req->page_token();
  if (req->state() != v1::JOB_STATE_UNSPECIFIED) o.state = FromProto(req->state());
  auto page = store_->List(o);
  if (!page.ok()) return Done(ctx, ToGrpc(page.status()));
  for (const JobRecord& r : page->jobs) *resp->add_jobs() = ToProto(r, false);
  resp->set_next_page_token(page->next_page_token);
  return Done(ctx, grpc::Status::OK);
}

grpc::ServerUnaryReactor* NimbusServiceImpl::CancelJob(grpc::CallbackServerContext* ctx,
                                                       const v1::CancelJobRequest* req,
                                                       v1::CancelJobResponse* resp) {
  auto rec = store_->RequestCancel(req->job_id(), NowMs());
  if (!rec.ok()) return Done(ctx, ToGrpc(rec.status()));
  pool_->Cancel(req->job_id());
  spdlog::info("job={} event=cancel_requested state={}", rec->id,
               v1::JobState_Name(ToProto(rec->state)));
  *resp->mutable_job() = ToProto(*rec, false);
  if (rec->state == JobState::kCancelled) hub_->PublishJob(resp->job());
  return Done(ctx, grpc::Status::OK);
}

grpc::ServerWriteReactor<v1::WatchJobResponse>* NimbusServiceImpl::WatchJob(
    grpc::CallbackServerContext* ctx, const v1::WatchJobRequest* req) {
  auto rec = store_->Get(req->job_id());
  if (!rec.ok()) {
    struct Fail : grpc::ServerWriteReactor<v1::WatchJobResponse> {
      explicit Fail(const grpc::Status& s) { Finish(s); }
      void OnDone() override { delete this; }
    };
    return new Fail(ToGrpc(rec.status()));
  }
  v1::Job initial = ToProto(*rec, false);
  if (auto live = hub_->Latest(req->job_id()); live && live->state() == initial.state())
    initial = *live;
  return new WatchReactor(hub_, store_, results_, *req, initial);
}

grpc::ServerWriteReactor<v1::FetchResultResponse>* NimbusServiceImpl::FetchResult(
    grpc::CallbackServerContext* ctx, const v1::FetchResultRequest* req) {
  struct Fail : grpc::ServerWriteReactor<v1::FetchResultResponse> {
    explicit Fail(const grpc::Status& s) { Finish(s); }
    void OnDone() override { delete this; }
  };
  auto rec = store_->Get(req->job_id());
  if (!rec.ok()) return new Fail(ToGrpc(rec.status()));
  // Further files (book pages) of a running job can be fetched as soon as
  // they are listed; everything else waits for success.
  const bool running = rec->state == JobState::kRunning;
  if (rec->state != JobState::kSucceeded && !(running && !req->file_name().empty()))
    return new Fail(
        grpc::Status(grpc::StatusCode::FAILED_PRECONDITION,
                     absl::StrCat("job ", rec->id, " is ", v1::JobState_Name(ToProto(rec->state)),
                                  "; results exist only for JOB_STATE_SUCCEEDED")));
  uint64_t size = rec->result_size;
  std::string sha256 = rec->result_sha256;
  if (!req->file_name().empty()) {
    bool found = false;
    for (const StoredFile& f : results_->ListFiles(rec->id, running))
      if (f.name == req->file_name()) {
        size = f.size;
        sha256 = f.sha256;
        found = true;
      }
    if (!found)
      return new Fail(grpc::Status(
          grpc::StatusCode::NOT_FOUND,
          absl::StrCat("job ", rec->id, " has no result file '", req->file_name(), "'")));
  }
  if (req->offset() > size)
    return new Fail(grpc::Status(
        grpc::StatusCode::OUT_OF_RANGE,
        absl::StrCat("offset ", req->offset(), " is past the end (", size, " bytes)")));
  // Committed further files live under the job id (the result key).
  return new FetchReactor(results_, req->file_name().empty() ? rec->result_key : rec->id,
                          req->file_name(), running, req->offset(), size, sha256);
}

namespace {

// Receives one asset upload. The first message announces hash, size and
// name; bytes are hashed while they arrive and the file is stored only when
// both match at the end of the stream.
class UploadReactor : public grpc::ServerReadReactor<v1::UploadAssetRequest> {
 public:
  UploadReactor(AssetStore* assets, v1::UploadAssetResponse* resp) : assets_(assets), resp_(resp) {
    StartRead(&req_);
  }

  void OnReadDone(bool ok) override {
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
      auto u = assets_->Begin(req_.sha256(), req_.size_bytes(), req_.file_name());
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

  void OnCancel() override {}
  void OnDone() override { delete this; }

 private:
  AssetStore* assets_;
  v1::UploadAssetResponse* resp_;
  v1::UploadAssetRequest req_;
  std::string sha256_;
  std::unique_ptr<AssetStore::Upload> upload_;
};

}  // namespace

grpc::ServerReadReactor<v1::UploadAssetRequest>* NimbusServiceImpl::UploadAsset(
    grpc::CallbackServerContext* ctx, v1::UploadAssetResponse* resp) {
  if (!assets_) {
    struct Fail : grpc::ServerReadReactor<v1::UploadAssetRequest> {
      Fail() { Finish(grpc::Status(grpc::StatusCode::UNIMPLEMENTED, "no asset store")); }
      void OnDone() override { delete this; }
    };
    return new Fail();
  }
  return new UploadReactor(assets_, resp);
}

}  // namespace nimbus::server
