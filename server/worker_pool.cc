#include "server/worker_pool.h"

#include <spdlog/spdlog.h>

#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <chrono>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "absl/strings/str_replace.h"
#include "core/io/metadata_keys.h"
#include "server/bounded_text.h"
#include "server/job_runner.h"
#include "server/job_view.h"
#include "server/shard_runner.h"
#include "server/untrusted_file.h"

namespace nimbus::server {

namespace {

using Clock = std::chrono::steady_clock;

v1::ProgressPhase ToProto(JobPhase phase) {
  switch (phase) {
    case JobPhase::kPreparing: return v1::PROGRESS_PHASE_PREPARING;
    case JobPhase::kIterating: return v1::PROGRESS_PHASE_ITERATING;
    case JobPhase::kWriting: return v1::PROGRESS_PHASE_WRITING;
  }
  return v1::PROGRESS_PHASE_UNSPECIFIED;
}

double Seconds(Clock::duration d) { return std::chrono::duration<double>(d).count(); }

// A failed job's error as its owner reads it: the writers name the files
// they write, and the server's directories are none of a client's business,
// so the job's scratch file and its folders keep only their own names.
std::string ClientError(absl::string_view message, const std::filesystem::path& scratch) {
  std::string out = absl::StrReplaceAll(message, {{scratch.parent_path().string() + "/", ""}});
  return absl::StrReplaceAll(out, {{scratch.parent_path().parent_path().string() + "/", ""}});
}

// TBB starts its scheduler, loads its allocator and starts its threads on
// first use, a few milliseconds; a worker does it before it looks for a job,
// so a new server's first job does not wait for it.
void WarmUpEngineThreads(int threads) {
  tbb::task_arena arena(threads);
  arena.execute([&] { tbb::parallel_for(0, threads, [](int) {}); });
}

// Stops the engine when the job is cancelled or the server shuts down.
class JobInterrupter : public Interrupter {
 public:
  JobInterrupter(const std::atomic<bool>* cancel, const std::atomic<bool>* shutdown)
      : cancel_(cancel), shutdown_(shutdown) {}
  bool WasInterrupted(uint64_t, uint64_t) override {
    return cancel_->load(std::memory_order_relaxed) || shutdown_->load(std::memory_order_relaxed);
  }

 private:
  const std::atomic<bool>* cancel_;
  const std::atomic<bool>* shutdown_;
};

}  // namespace

// The worker's side of a running job: progress to the hub and the store's
// lease, previews on demand, warnings and stats for the final record.
class WorkerPool::Context : public JobContext {
 public:
  Context(WorkerPool* pool, const JobRecord& record, const std::string& worker_id,
          std::shared_ptr<std::atomic<bool>> cancel, const v1::JobSpec& spec)
      : pool_(pool),
        record_(record),
        worker_id_(worker_id),
        cancel_(std::move(cancel)),
        interrupter_(cancel_.get(), &pool->shutdown_),
        spec_hash_(spec::SpecHash(spec)),
        view_(ToProto(record, false)),
        phase_start_(Clock::now()),
        last_heartbeat_(phase_start_) {
    // A claimed job prepares first (conversion, meshes) until its runner
    // reports a phase of its own.
    view_.mutable_progress()->set_phase(v1::PROGRESS_PHASE_PREPARING);
  }

  const std::string& job_id() const override { return record_.id; }
  int threads() const override { return pool_->threads_per_job_; }
  Interrupter* interrupter() override { return &interrupter_; }

  uint64_t memory_budget() const override { return pool_->options_.limits.max_memory_bytes; }

  absl::Status ReportProgress(const JobProgress& progress) override {
    auto* p = view_.mutable_progress();
    const v1::ProgressPhase phase = ToProto(progress.phase);
    if (phase != p->phase()) phase_start_ = Clock::now();  // rates are per phase
    const double elapsed = std::max(1e-6, Seconds(Clock::now() - phase_start_));
    const uint64_t done = progress.done, total = progress.total;
    const double rate = double(done) / elapsed;
    p->set_phase(phase);
    p->set_unit(std::string(progress.unit));
    p->set_done(done);
    p->set_total(total);
    p->set_rate(rate);
    p->set_eta_seconds(rate > 0 && total > done ? double(total - done) / rate : 0);
    view_.set_state(v1::JOB_STATE_RUNNING);
    pool_->hub_->PublishJob(view_);
    if (!record_.parent_id.empty() &&
        Clock::now() - last_parent_publish_ >= std::chrono::milliseconds(500)) {
      last_parent_publish_ = Clock::now();
      pool_->PublishParent(record_.parent_id, record_.id, done);
    }
    if (Clock::now() - last_heartbeat_ >= std::chrono::milliseconds(pool_->options_.heartbeat_ms)) {
      last_heartbeat_ = Clock::now();
      auto hb = pool_->store_->Heartbeat(record_.id, worker_id_, NowMs(), pool_->options_.lease_ms,
                                         done, total);
      if (!hb.ok()) {
        spdlog::warn("job={} event=lost_claim reason=\"{}\"", record_.id, hb.status().ToString());
        return absl::AbortedError("lost the job's claim");
      }
      if (*hb) *cancel_ = true;
      // Watchers on other replicas (a shared store only).
      if (auto wishes = pool_->store_->PreviewWishes(record_.id, NowMs()); wishes.ok())
        remote_wishes_ = std::move(*wishes);
    }
    return absl::OkStatus();
  }

  bool WantsPreview() override { return !record_.parent_id.empty() || !Wanted().empty(); }

  void MaybePublishPreview(const std::vector<const CountGrid*>& parts, const GridFrame& frame,
                           const DensityOptions& density, uint64_t done) override {
    for (const PreviewTarget& want : Wanted()) {
      auto& last = last_preview_[want.resolution];
      if (last != Clock::time_point{} &&
          Seconds(Clock::now() - last) < std::max(0.05, want.interval_seconds))
        continue;
      last = Clock::now();
      auto made = MakePreview(parts, frame, density, done, want.resolution, ++preview_sequence_);
      if (!made.ok()) continue;
      v1::Preview preview = *std::move(made);
      if (want.remote) {
        auto st = pool_->store_->PutPreview(record_.id, want.resolution, preview.sequence(),
                                            preview.SerializeAsString());
        if (!st.ok()) spdlog::warn("job={} event=put_preview_failed reason=\"{}\"", record_.id,
                                   st.ToString());
      }
      pool_->hub_->PublishPreview(record_.id, want.resolution, std::move(preview));
    }
    if (!record_.parent_id.empty()) PublishParentPreview(parts, frame, density, done);
  }

  // A preview of the counts at `resolution`. The file says which preview
  // and how far the run was, so a client that names its files densely
  // loses neither.
  static absl::StatusOr<v1::Preview> MakePreview(const std::vector<const CountGrid*>& parts,
                                                 const GridFrame& frame,
                                                 const DensityOptions& density, uint64_t done,
                                                 uint32_t resolution, uint64_t sequence) {
    const int factor = DownsampleFactor(frame.resolution, int(resolution));
    return PreviewOf(DownsampleCounts(parts, factor), DownsampleFrame(frame, factor), density,
                     done, sequence);
  }
  static absl::StatusOr<v1::Preview> PreviewOf(const CountGrid& coarse,
                                               const GridFrame& coarse_frame,
                                               const DensityOptions& density, uint64_t done,
                                               uint64_t sequence) {
    auto bytes = DensityVdbBytes(coarse, coarse_frame, density,
                                 {{meta_key::kPreviewSequence, int64_t(sequence)},
                                  {meta_key::kPreviewDone, int64_t(done)}});
    if (!bytes.ok()) return bytes.status();
    v1::Preview preview;
    preview.set_sequence(sequence);
    preview.set_vdb(*std::move(bytes));
    preview.add_resolution(coarse_frame.resolution.x);
    preview.add_resolution(coarse_frame.resolution.y);
    preview.add_resolution(coarse_frame.resolution.z);
    preview.set_done(done);
    return preview;
  }

  // Watchers of a sharded job see the sum of its shards' newest counts
  // (those run by this process), so the preview covers every shard.
  void PublishParentPreview(const std::vector<const CountGrid*>& parts, const GridFrame& frame,
                            const DensityOptions& density, uint64_t done) {
    const std::string& parent = record_.parent_id;
    for (const JobHub::PreviewWant& want : pool_->hub_->WantedPreviews(parent)) {
      auto& last = last_parent_preview_[want.resolution];
      if (last != Clock::time_point{} &&
          Seconds(Clock::now() - last) < std::max(0.05, want.interval_seconds))
        continue;
      last = Clock::now();
      const int factor = DownsampleFactor(frame.resolution, int(want.resolution));
      auto [sum, sequence] = pool_->SumParentPreview(parent, record_.shard_index, want.resolution,
                                                     DownsampleCounts(parts, factor));
      auto preview = PreviewOf(sum, DownsampleFrame(frame, factor), density, done, sequence);
      if (!preview.ok()) continue;
      pool_->hub_->PublishPreview(parent, want.resolution, *std::move(preview));
    }
  }

  void MaybePublishPicturePreview(
      const std::function<absl::StatusOr<PicturePreview>(int resolution)>& make,
      uint64_t done) override {
    for (const JobHub::PreviewWant& want : pool_->hub_->WantedPreviews(record_.id)) {
      auto& last = last_preview_[want.resolution];
      if (last != Clock::time_point{} &&
          Seconds(Clock::now() - last) < std::max(0.05, want.interval_seconds))
        continue;
      last = Clock::now();
      auto pic = make(int(want.resolution));
      if (!pic.ok()) continue;
      const uint64_t sequence = ++preview_sequence_;
      DensityOptions density;
      density.mapping = DensityMapping::kSqrt;
      auto bytes = DensityVdbBytes(pic->counts, pic->frame, density,
                                   {{meta_key::kPreviewSequence, int64_t(sequence)},
                                    {meta_key::kPreviewDone, int64_t(done)}});
      if (!bytes.ok()) continue;
      v1::Preview preview;
      preview.set_sequence(sequence);
      preview.set_vdb(std::move(*bytes));
      for (int a = 0; a < 3; ++a) preview.add_resolution(pic->frame.resolution[a]);
      preview.set_done(done);
      preview.set_png(std::move(pic->png));
      pool_->hub_->PublishPreview(record_.id, want.resolution, std::move(preview));
    }
  }

  void SetStat(const std::string& key, uint64_t value) override {
    (*view_.mutable_stats())[key] = value;
  }
  void AddWarning(const std::string& warning) override { warnings_.push_back(warning); }
  std::filesystem::path ResultScratchPath() override {
    return pool_->results_->ScratchPath(record_.id);
  }
  absl::StatusOr<std::vector<JellyPoke>> TakePokes(uint64_t frame) override {
    auto taken = pool_->store_->TakePokes(record_.id, worker_id_, int64_t(frame));
    if (!taken.ok()) {
      spdlog::warn("job={} event=take_pokes_failed reason=\"{}\"", record_.id,
                   taken.status().ToString());
      if (absl::IsFailedPrecondition(taken.status()))
        return absl::AbortedError("lost the job's claim");
      return taken.status();
    }
    std::vector<JellyPoke> out;
    for (const PokeRecord& r : *taken) {
      JellyPoke p;
      p.frame = frame;
      p.body = r.body;
      p.kind = r.drag ? JellyPoke::Kind::kDrag : JellyPoke::Kind::kImpulse;
      p.vector = {r.x, r.y, r.z};
      p.stiffness = r.drag_stiffness;
      p.frames = r.drag_frames;
      out.push_back(p);
    }
    if (!out.empty()) spdlog::info("job={} event=pokes frame={} count={}", record_.id, frame, out.size());
    return out;
  }
  Metadata BaseMetadata() const override {
    // Nothing per job or per run (id, time): a result's bytes depend only
    // on its spec, so identical specs give identical files.
    return {{"nimbus_spec_hash", spec_hash_}, {"nimbus_version", std::string(NIMBUS_VERSION)}};
  }

 private:
  struct PreviewTarget {
    uint32_t resolution;
    double interval_seconds;
    bool remote;  // also wanted by watchers on other replicas: store it
  };
  // This process's watchers' wants and other replicas' wishes, merged.
  std::vector<PreviewTarget> Wanted() const {
    std::vector<PreviewTarget> out;
    for (const JobHub::PreviewWant& w : pool_->hub_->WantedPreviews(record_.id))
      out.push_back({w.resolution, w.interval_seconds, false});
    for (const PreviewWish& w : remote_wishes_) {
      auto it = std::find_if(out.begin(), out.end(),
                             [&](const PreviewTarget& t) { return t.resolution == w.resolution; });
      if (it == out.end()) {
        out.push_back({w.resolution, w.interval_seconds, true});
      } else {
        it->remote = true;
        it->interval_seconds = std::min(it->interval_seconds, w.interval_seconds);
      }
    }
    return out;
  }
  std::vector<PreviewWish> remote_wishes_;

 public:
  const v1::Job& view() const { return view_; }
  const std::vector<std::string>& warnings() const { return warnings_; }
  bool cancelled() const { return *cancel_; }

 private:
  WorkerPool* pool_;
  const JobRecord& record_;
  std::string worker_id_;
  std::shared_ptr<std::atomic<bool>> cancel_;
  JobInterrupter interrupter_;
  std::string spec_hash_;
  v1::Job view_;
  Clock::time_point phase_start_;
  Clock::time_point last_heartbeat_;
  std::map<uint32_t, Clock::time_point> last_preview_;
  std::map<uint32_t, Clock::time_point> last_parent_preview_;
  Clock::time_point last_parent_publish_;
  uint64_t preview_sequence_ = 0;
  std::vector<std::string> warnings_;
};

WorkerPool::WorkerPool(JobStore* store, ResultStore* results, JobHub* hub, WorkerOptions options)
    : store_(store), results_(results), hub_(hub), options_(std::move(options)) {
  const int hw = std::max(1u, std::thread::hardware_concurrency());
  const int workers = std::max(1, options_.workers);
  threads_per_job_ =
      options_.threads_per_job > 0 ? options_.threads_per_job : std::max(1, hw / workers);
}

WorkerPool::~WorkerPool() { Stop(); }

void WorkerPool::Start() {
  for (int i = 0; i < std::max(1, options_.workers); ++i)
    threads_.emplace_back([this, i] { Loop(i); });
}

void WorkerPool::Stop() {
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (stopping_ && threads_.empty()) return;
    stopping_ = true;
  }
  shutdown_ = true;
  wake_.notify_all();
  for (auto& t : threads_) t.join();
  threads_.clear();
}

void WorkerPool::Wake() {
  {
    std::lock_guard<std::mutex> lock(mu_);
    ++wake_generation_;
  }
  wake_.notify_one();
}

bool WorkerPool::IsRunning(const std::string& job_id) {
  std::lock_guard<std::mutex> lock(mu_);
  return running_.count(job_id) > 0;
}

void WorkerPool::Cancel(const std::string& job_id) {
  std::lock_guard<std::mutex> lock(mu_);
  auto it = running_.find(job_id);
  if (it != running_.end()) *it->second = true;
}

void WorkerPool::Loop(int index) {
  const std::string worker_id = absl::StrCat(options_.instance_id, "/w", index);
  WarmUpEngineThreads(threads_per_job_);
  while (true) {
    uint64_t generation;
    {
      std::lock_guard<std::mutex> lock(mu_);
      if (stopping_) return;
      generation = wake_generation_;
    }
    std::vector<JobRecord> given_up;
    auto claimed =
        store_->ClaimNext(worker_id, NowMs(), options_.lease_ms, options_.max_attempts, &given_up);
    PublishGivenUp(given_up);
    if (!claimed.ok()) {
      spdlog::error("worker={} claim failed: {}", worker_id, claimed.status().ToString());
    } else if (claimed->has_value()) {
      RunJob(**claimed, worker_id);
      continue;
    }
    // Idle: sleep until woken, or poll now and then for jobs other replicas
    // released or whose leases lapsed.
    std::unique_lock<std::mutex> lock(mu_);
    wake_.wait_for(lock, std::chrono::seconds(1),
                   [&] { return stopping_ || wake_generation_ != generation; });
  }
}

void WorkerPool::RunJob(const JobRecord& record, const std::string& worker_id) {
  const std::string& id = record.id;
  auto cancel = std::make_shared<std::atomic<bool>>(record.cancel_requested);
  {
    std::lock_guard<std::mutex> lock(mu_);
    running_[id] = cancel;
  }
  spdlog::info("job={} event=start attempt={} worker={}", id, record.attempts, worker_id);

  v1::JobSpec spec;
  const bool parsed = spec.ParseFromString(record.spec);
  Context ctx(this, record, worker_id, cancel, spec);
  hub_->PublishJob(ctx.view());

  absl::Status status = absl::DataLossError("the stored spec is unreadable");
  if (parsed) {
    // Core returns statuses, but an allocation can still throw; a poison
    // job must end as FAILED, not take the worker thread with it.
    try {
      status = ConvertAndRun(spec, record, ctx);
    } catch (const std::exception& e) {
      status = absl::InternalError(
          absl::StrCat("the job stopped on an exception: ", BoundText(e.what(), 512)));
    }
  }

  Completion done;
  std::vector<std::string> warnings;
  if (!record.warnings.empty()) warnings.push_back(record.warnings);
  warnings.insert(warnings.end(), ctx.warnings().begin(), ctx.warnings().end());
  done.warnings = absl::StrJoin(warnings, "\n");
  bool release = false;
  if (absl::IsAborted(status)) {
    // Another worker owns the job now: write nothing.
  } else if (absl::IsCancelled(status)) {
    if (shutdown_ && !ctx.cancelled()) {
      release = true;
    } else {
      done.state = JobState::kCancelled;
      done.error = "cancelled by request";
      done.error_code = int(absl::StatusCode::kCancelled);
    }
  } else if (!status.ok()) {
    done.state = JobState::kFailed;
    done.error =
        BoundText(ClientError(status.message(), ctx.ResultScratchPath()), kMaxErrorBytes);
    done.error_code = int(status.code());
  } else if (auto stored = results_->Commit(id, ctx.ResultScratchPath()); !stored.ok()) {
    done.state = JobState::kFailed;
    done.error =
        BoundText(ClientError(stored.status().message(), ctx.ResultScratchPath()), kMaxErrorBytes);
    done.error_code = int(stored.status().code());
  } else {
    done.state = JobState::kSucceeded;
    done.result_key = stored->key;
    done.result_size = stored->size;
    done.result_sha256 = stored->sha256;
  }

  if (absl::IsAborted(status)) {
    spdlog::warn("job={} event=abandoned", id);
  } else if (release) {
    auto st = store_->Release(id, worker_id);
    spdlog::info("job={} event=released status=\"{}\"", id, st.ToString());
  } else {
    if (done.state == JobState::kSucceeded) {
      // Record the finished progress; heartbeats only sample it.
      const auto& p = ctx.view().progress();
      (void)store_->Heartbeat(id, worker_id, NowMs(), options_.lease_ms, p.total(), p.total());
    }
    if (RecordEnd(id, worker_id, done))
      spdlog::info("job={} event=end state={} error=\"{}\"", id,
                   v1::JobState_Name(ToProto(done.state)), done.error);
    // A merged job's partials are spent.
    if (done.state == JobState::kSucceeded && record.shard_count > 1 &&
        record.parent_id.empty())
      if (auto shards = store_->ListShards(id); shards.ok())
        for (const JobRecord& s : *shards) (void)results_->Delete(s.id);
  }
  // The parent learns of its shard's end (it may have ended with it).
  if (!record.parent_id.empty()) PublishParent(record.parent_id, "", 0);
  if (auto final_record = store_->Get(id); final_record.ok()) {
    v1::Job final_view = ToProto(*final_record, false);
    *final_view.mutable_stats() = ctx.view().stats();
    final_view.mutable_progress()->set_rate(ctx.view().progress().rate());
    hub_->PublishJob(final_view);
  }
  hub_->Forget(id);
  std::lock_guard<std::mutex> lock(mu_);
  running_.erase(id);
}

// A Complete the store refuses (an error it cannot take, a write that
// fails) is tried once more with a short error and no warnings. If that
// fails too, the attempt is abandoned with its reason: the job goes back to
// the queue, and ClaimNext fails it once its attempts run out.
bool WorkerPool::RecordEnd(const std::string& id, const std::string& worker_id,
                           const Completion& done) {
  absl::Status st = store_->Complete(id, worker_id, done, NowMs());
  if (st.ok()) return true;
  // Not ours any more (or gone): nothing to record.
  if (absl::IsFailedPrecondition(st) || absl::IsNotFound(st)) return false;
  spdlog::error("job={} event=complete_failed error=\"{}\"", id, BoundText(st.ToString(), 512));
  Completion brief = done;
  brief.error = BoundText(done.error, 256);
  brief.warnings.clear();
  st = store_->Complete(id, worker_id, brief, NowMs());
  if (st.ok()) return true;
  if (absl::IsFailedPrecondition(st) || absl::IsNotFound(st)) return false;
  const std::string reason =
      absl::StrCat("could not record the job's end (", BoundText(st.message(), 256), ")",
                   done.error.empty() ? "" : "; it ended: ", BoundText(done.error, 256));
  const int code = done.error_code != 0 ? done.error_code : int(st.code());
  st = store_->AbandonAttempt(id, worker_id, reason, code);
  spdlog::error("job={} event=attempt_abandoned reason=\"{}\" status=\"{}\"", id, reason,
                BoundText(st.ToString(), 512));
  return false;
}

void WorkerPool::PublishGivenUp(const std::vector<JobRecord>& jobs) {
  for (const JobRecord& job : jobs) {
    spdlog::warn("job={} event=gave_up attempts={} error=\"{}\"", job.id, job.attempts,
                 BoundText(job.error, 512));
    hub_->PublishJob(ToProto(job, false));
    hub_->Forget(job.id);
  }
}

void WorkerPool::PublishParent(const std::string& parent_id, const std::string& shard_id,
                               uint64_t live_done) {
  auto parent = store_->Get(parent_id);
  auto shards = store_->ListShards(parent_id);
  if (!parent.ok() || !shards.ok()) return;
  v1::Job view = ToProto(*parent, false);
  AggregateShards(*shards, view, shard_id, live_done);
  hub_->PublishJob(view);
  if (IsTerminal(parent->state)) {
    hub_->Forget(parent_id);
    std::lock_guard<std::mutex> lock(mu_);
    parent_previews_.erase(parent_id);
  }
}

std::pair<CountGrid, uint64_t> WorkerPool::SumParentPreview(const std::string& parent_id,
                                                           uint32_t shard, uint32_t resolution,
                                                           CountGrid coarse) {
  std::lock_guard<std::mutex> lock(mu_);
  ParentPreviews& p = parent_previews_[parent_id];
  const Int3 res = coarse.resolution();
  const bool color = coarse.has_color();
  p.latest.insert_or_assign({resolution, shard}, std::move(coarse));
  CountGrid sum(res, color);
  for (const auto& [key, grid] : p.latest)
    if (key.first == resolution && grid.resolution() == res) sum.Merge(grid);
  return {std::move(sum), ++p.sequence};
}

absl::Status WorkerPool::RunShardOrMerge(const JobPlan& plan, const JobRecord& record,
                                         JobContext& ctx) {
  if (!record.parent_id.empty())
    return RunShard(plan, record.shard_index, record.shard_count, ctx);
  auto shards = store_->ListShards(record.id);
  if (!shards.ok()) return shards.status();
  if (shards->size() != record.shard_count)
    return absl::DataLossError(absl::StrCat("job ", record.id, " has ", shards->size(),
                                            " shards, expected ", record.shard_count));
  auto read = [&](uint32_t k) -> absl::StatusOr<std::string> {
    const std::string& key = (*shards)[k].result_key;
    auto size = results_->Size(key);
    if (!size.ok()) return size.status();
    std::string bytes;
    bytes.reserve(*size);
    while (bytes.size() < *size) {
      const uint64_t left = *size - bytes.size();
      auto piece = results_->Read(key, bytes.size(), std::min(left, uint64_t{64} << 20));
      if (!piece.ok()) return piece.status();
      if (piece->empty()) break;
      bytes += *piece;
    }
    return bytes;
  };
  return RunMerge(plan, record.shard_count, read, ctx);
}

absl::Status WorkerPool::ConvertAndRun(const v1::JobSpec& spec, const JobRecord& record,
                                       JobContext& ctx) {
  // The plan is rebuilt from the stored spec on purpose: the spec is the
  // durable, versioned record; conversion is deterministic and cheap next
  // to the run (meshes are parsed again, so a restarted job reads the same
  // files); a stored plan would need a second format holding parsed meshes.
  // Memory admission (the pilot census) is not repeated: it ran once at
  // submit, and the run-time budget is the safety net.
  // Files are parsed in this process only after a sandboxed reader read
  // them whole (once per asset: the result is remembered), so a poison
  // file stored before that check existed fails here, not in the worker.
  const spec::Limits& limits = options_.limits;
  if (auto st = CheckSpecAssets(spec, limits.asset_dir, limits.allow_local_paths); !st.ok())
    return st;
  auto plan = spec::ConvertSpec(spec, options_.limits);
  if (!plan.ok()) return plan.status();
  // Every engine thread of this job, TBB loops included, runs in its own
  // arena sized by --threads-per-job.
  tbb::task_arena arena(threads_per_job_);
  absl::Status status;
  arena.execute([&] {
    ctx.SetStat("arena_threads", uint64_t(tbb::this_task_arena::max_concurrency()));
    status = record.shard_count > 1 ? RunShardOrMerge(*plan, record, ctx)
                                    : RunJobPlan(*plan, ctx);
  });
  return status;
}

}  // namespace nimbus::server
