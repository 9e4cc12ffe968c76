#include "server/worker_pool.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "core/chaos_game.h"
#include "core/vdb_io.h"
#include "server/job_view.h"

namespace nimbus::server {

namespace {

using Clock = std::chrono::steady_clock;

double Seconds(Clock::duration d) { return std::chrono::duration<double>(d).count(); }

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

WorkerPool::WorkerPool(JobStore* store, ResultStore* results, JobHub* hub, WorkerOptions options)
    : store_(store), results_(results), hub_(hub), options_(std::move(options)) {
  const int hw = std::max(1u, std::thread::hardware_concurrency());
  const int workers = std::max(1, options_.workers);
  threads_per_job_ =
      options_.threads_per_job > 0 ? options_.threads_per_job : std::max(1, hw / workers);
}

WorkerPool::~WorkerPool() { Stop(); }

void WorkerPool::Start() {
  for (int i = 0; i < std::max(1, options_.workers); ++i) threads_.emplace_back([this, i] { Loop(i); });
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

void WorkerPool::Cancel(const std::string& job_id) {
  std::lock_guard<std::mutex> lock(mu_);
  auto it = running_.find(job_id);
  if (it != running_.end()) *it->second = true;
}

void WorkerPool::Loop(int index) {
  const std::string worker_id = absl::StrCat(options_.instance_id, "/w", index);
  while (true) {
    uint64_t generation;
    {
      std::lock_guard<std::mutex> lock(mu_);
      if (stopping_) return;
      generation = wake_generation_;
    }
    auto claimed = store_->ClaimNext(worker_id, NowMs(), options_.lease_ms);
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
  v1::Job view = ToProto(record, /*with_spec=*/false);
  hub_->PublishJob(view);

  Completion done;
  std::vector<std::string> warnings;
  if (!record.warnings.empty()) warnings.push_back(record.warnings);
  bool released = false;

  auto finish = [&](JobState state, std::string error) {
    done.state = state;
    done.error = std::move(error);
  };

  v1::JobSpec spec;
  absl::StatusOr<spec::ConvertedJob> job = absl::InvalidArgumentError("stored spec is unreadable");
  if (spec.ParseFromString(record.spec)) job = spec::ConvertSpec(spec, options_.limits, threads_per_job_);
  if (!job.ok()) {
    finish(JobState::kFailed, std::string(job.status().message()));
  } else {
    ChaosGameParams params = job->chaos_game;
    auto game = ChaosGame::Create(std::move(params), threads_per_job_);
    if (!game.ok()) {
      finish(JobState::kFailed, std::string(game.status().message()));
    } else {
      JobInterrupter interrupter(cancel.get(), &shutdown_);
      const uint64_t total = job->chaos_game.iterations;
      const auto start = Clock::now();
      auto last_heartbeat = start;
      std::map<uint32_t, Clock::time_point> last_preview;
      uint64_t preview_sequence = 0;
      uint64_t step = ChaosGame::kChunkIterations * threads_per_job_;
      absl::Status status;
      while (!(*game)->done()) {
        const uint64_t before = (*game)->stats().iterations_done;
        const auto round_start = Clock::now();
        status = (*game)->RunUntil(before + step, &interrupter);
        if (!status.ok()) break;
        const uint64_t now_done = (*game)->stats().iterations_done;
        // Aim for rounds of ~0.2 s so progress and previews stay fresh.
        const double round_s = std::max(1e-4, Seconds(Clock::now() - round_start));
        step = std::clamp<uint64_t>(uint64_t(double(now_done - before) * 0.2 / round_s),
                                    ChaosGame::kChunkIterations, total);
        const double elapsed = std::max(1e-6, Seconds(Clock::now() - start));
        const double rate = double(now_done) / elapsed;
        auto* p = view.mutable_progress();
        p->set_done(now_done);
        p->set_total(total);
        p->set_rate(rate);
        p->set_eta_seconds(rate > 0 ? double(total - now_done) / rate : 0);
        view.set_state(v1::JOB_STATE_RUNNING);
        hub_->PublishJob(view);

        for (const JobHub::PreviewWant& want : hub_->WantedPreviews(id)) {
          auto& last = last_preview[want.resolution];
          if (last != Clock::time_point{} &&
              Seconds(Clock::now() - last) < std::max(0.05, want.interval_seconds))
            continue;
          last = Clock::now();
          const int factor = DownsampleFactor(job->frame.resolution, int(want.resolution));
          std::vector<const CountGrid*> parts;
          for (const CountGrid& g : (*game)->partial_counts()) parts.push_back(&g);
          const CountGrid coarse = DownsampleCounts(parts, factor);
          const GridFrame frame = DownsampleFrame(job->frame, factor);
          auto bytes = DensityVdbBytes(coarse, frame, job->density, {});
          if (!bytes.ok()) continue;
          v1::Preview preview;
          preview.set_sequence(++preview_sequence);
          preview.set_vdb(std::move(*bytes));
          preview.add_resolution(frame.resolution.x);
          preview.add_resolution(frame.resolution.y);
          preview.add_resolution(frame.resolution.z);
          preview.set_done(now_done);
          hub_->PublishPreview(id, want.resolution, std::move(preview));
        }

        if (Clock::now() - last_heartbeat >= std::chrono::milliseconds(options_.heartbeat_ms)) {
          last_heartbeat = Clock::now();
          auto hb = store_->Heartbeat(id, worker_id, NowMs(), options_.lease_ms, now_done, total);
          if (!hb.ok()) {
            // Lost the claim (lease lapsed and someone else took it): stop.
            spdlog::warn("job={} event=lost_claim reason=\"{}\"", id, hb.status().ToString());
            status = absl::AbortedError("lost the job's claim");
            break;
          }
          if (*hb) *cancel = true;
        }
      }
      const ChaosGameStats stats = (*game)->stats();
      (*view.mutable_stats())["outside"] = stats.outside;
      (*view.mutable_stats())["reseeded"] = stats.reseeded;
      if (stats.iterations_done > 0 && stats.reseeded * 1000 > stats.iterations_done)
        warnings.push_back(absl::StrCat(
            "high bad-point rate: ", stats.reseeded, " walkers re-seeded after non-finite points in ",
            stats.iterations_done, " steps"));
      if (stats.iterations_done > 0 && stats.outside * 2 > stats.iterations_done)
        warnings.push_back(absl::StrCat(stats.outside, " of ", stats.iterations_done,
                                        " points fell outside the grid bounds"));
      if (absl::IsAborted(status)) {
        hub_->Forget(id);
        std::lock_guard<std::mutex> lock(mu_);
        running_.erase(id);
        return;  // another worker owns it now; write nothing
      }
      if (absl::IsCancelled(status)) {
        if (shutdown_ && !*cancel) {
          released = true;
        } else {
          finish(JobState::kCancelled, "cancelled by request");
        }
      } else if (!status.ok()) {
        finish(JobState::kFailed, std::string(status.message()));
      } else {
        const CountGrid counts = (*game)->TakeCounts();
        const Metadata meta = {
            {"nimbus_seed", int64_t(job->chaos_game.seed)},
            {"nimbus_iterations", int64_t(stats.iterations_done)},
            {"nimbus_spec_hash", spec::SpecHash(spec)},
            {"nimbus_version", std::string(NIMBUS_VERSION)},
            {"nimbus_job_id", id},
            {"nimbus_outside", int64_t(stats.outside)},
            {"nimbus_reseeded", int64_t(stats.reseeded)},
        };
        const auto scratch = results_->ScratchPath(id);
        auto st = WriteDensityVdb(scratch, counts, job->frame, job->density, meta);
        if (!st.ok()) {
          finish(JobState::kFailed, std::string(st.message()));
        } else {
          auto stored = results_->Commit(id, scratch);
          if (!stored.ok()) {
            finish(JobState::kFailed, std::string(stored.status().message()));
          } else {
            finish(JobState::kSucceeded, "");
            done.result_key = stored->key;
            done.result_size = stored->size;
            done.result_sha256 = stored->sha256;
          }
        }
      }
    }
  }

  if (released) {
    auto st = store_->Release(id, worker_id);
    spdlog::info("job={} event=released status=\"{}\"", id, st.ToString());
  } else {
    done.warnings = absl::StrJoin(warnings, "\n");
    auto st = store_->Complete(id, worker_id, done, NowMs());
    if (!st.ok()) spdlog::error("job={} event=complete_failed error=\"{}\"", id, st.ToString());
    spdlog::info("job={} event=end state={} error=\"{}\"", id, v1::JobState_Name(ToProto(done.state)),
                 done.error);
  }
  auto final_record = store_->Get(id);
  if (final_record.ok()) {
    v1::Job final_view = ToProto(*final_record, false);
    *final_view.mutable_stats() = view.stats();
    if (final_record->state == JobState::kSucceeded) {
      final_view.mutable_progress()->set_rate(view.progress().rate());
    }
    hub_->PublishJob(final_view);
  }
  hub_->Forget(id);
  std::lock_guard<std::mutex> lock(mu_);
  running_.erase(id);
}

}  // namespace nimbus::server
