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

// Streams job snapshots to one watcher. Holds only the newest snapshot, so a
// slow client skips intermediate states instead of queueing them.
class WatchReactor : public grpc::ServerWriteReactor<v1::WatchJobResponse> {
 public:
  WatchReactor(JobHub* hub, JobStore* store, const v1::WatchJobRequest& req,
               const v1::Job& initial)
      : hub_(hub),
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
                             job.progress().done() != sent_done_ || job.attempts() != sent_attempts_;
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
  FetchReactor(ResultStore* results, std::string key, uint64_t offset, uint64_t size,
               std::string sha256)
      : results_(results), key_(std::move(key)), offset_(offset), size_(size) {
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
    auto data = results_->Read(key_, offset_, kFetchChunk);
    if (!data.ok()) return Finish(ToGrpc(data.status()));
    resp_.set_offset(offset_);
    offset_ += data->size();
    resp_.set_data(std::move(*data));
    sent_any_ = true;
    StartWrite(&resp_);
  }

  ResultStore* results_;
  std::string key_;
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

NimbusServiceImpl::NimbusServiceImpl(JobStore* store, ResultStore* results, JobHub* hub,
                                     WorkerPool* pool, spec::Limits limits)
    : store_(store), results_(results), hub_(hub), pool_(pool), limits_(limits) {}

grpc::ServerUnaryReactor* NimbusServiceImpl::SubmitJob(grpc::CallbackServerContext* ctx,
                                                       const v1::SubmitJobRequest* req,
                                                       v1::SubmitJobResponse* resp) {
  // Validation is cheap (no allocation of grids); it runs here so that the
  // client hears about a bad spec at once.
  auto job = spec::ConvertSpec(req->spec(), limits_, pool_->threads_per_job());
  if (!job.ok()) return Done(ctx, ToGrpc(job.status()));
  NewJob nj;
  nj.id = NewJobId();
  nj.name = job->name;
  req->spec().SerializeToString(&nj.spec);
  nj.request_id = req->request_id();
  nj.progress_total = job->total_work;
  for (const auto& w : job->warnings) nj.warnings += w + "\n";
  nj.estimated_memory_bytes = job->estimated_memory_bytes;
  auto rec = store_->Create(nj, NowMs());
  if (!rec.ok()) return Done(ctx, ToGrpc(rec.status()));
  spdlog::info("job={} event=submitted name={} work={}", rec->id, rec->name, rec->progress_total);
  *resp->mutable_job() = ToProto(*rec, true);
  if (rec->state == JobState::kQueued) hub_->PublishJob(resp->job());
  pool_->Wake();
  return Done(ctx, grpc::Status::OK);
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
  return new WatchReactor(hub_, store_, *req, initial);
}

grpc::ServerWriteReactor<v1::FetchResultResponse>* NimbusServiceImpl::FetchResult(
    grpc::CallbackServerContext* ctx, const v1::FetchResultRequest* req) {
  struct Fail : grpc::ServerWriteReactor<v1::FetchResultResponse> {
    explicit Fail(const grpc::Status& s) { Finish(s); }
    void OnDone() override { delete this; }
  };
  auto rec = store_->Get(req->job_id());
  if (!rec.ok()) return new Fail(ToGrpc(rec.status()));
  if (rec->state != JobState::kSucceeded)
    return new Fail(grpc::Status(
        grpc::StatusCode::FAILED_PRECONDITION,
        absl::StrCat("job ", rec->id, " is ", v1::JobState_Name(ToProto(rec->state)),
                     "; results exist only for JOB_STATE_SUCCEEDED")));
  if (req->offset() > rec->result_size)
    return new Fail(grpc::Status(grpc::StatusCode::OUT_OF_RANGE,
                                 absl::StrCat("offset ", req->offset(), " is past the end (",
                                              rec->result_size, " bytes)")));
  return new FetchReactor(results_, rec->result_key, req->offset(), rec->result_size,
                          rec->result_sha256);
}

}  // namespace nimbus::server
