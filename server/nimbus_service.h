// The nimbus.v1.NimbusService implementation on gRPC's callback API. gRPC's
// threads only move data: validation runs on the admission thread, store and
// result-file work on a small blocking executor, jobs in the WorkerPool.
#pragma once

#include <atomic>
#include <functional>
#include <memory>
#include <string>

#include "nimbus/v1/nimbus_service.grpc.pb.h"
#include "proto/spec_convert.h"
#include "server/admission.h"
#include "server/asset_store.h"
#include "server/auth.h"
#include "server/blocking_executor.h"
#include "server/job_hub.h"
#include "server/job_store.h"
#include "server/result_store.h"
#include "server/worker_pool.h"

namespace nimbus::server {

class NimbusServiceImpl final : public v1::NimbusService::CallbackService {
 public:
  NimbusServiceImpl(JobStore* store, ResultStore* results, AssetStore* assets, JobHub* hub,
                    WorkerPool* pool, spec::Limits limits);
  /// How long CancelJob waits for a job running in this process to stop
  /// before answering it RUNNING with cancel_requested (default 5 s).
  void set_cancel_wait_ms(int64_t ms) { cancel_wait_ms_ = ms; }
  /// Jobs above this many iterations that did not choose their shards are
  /// split (docs/sharding.md); 0: never.
  void set_auto_shard_iterations(uint64_t n) { auto_shard_iterations_ = n; }
  /// ListWorkers shows a replica lost once its last heartbeat is older.
  void set_lease_ms(int64_t ms) { lease_ms_ = ms; }
  /// Who may call (no tokens: everyone, as the anonymous admin), what each
  /// principal may store, and how long results are kept (0: for ever; only
  /// named in FetchResult's answer for an expired result).
  void set_security(TokenTable tokens, Quotas quotas, int64_t retention_ms) {
    tokens_ = std::move(tokens);
    quotas_ = quotas;
    retention_ms_ = retention_ms;
  }

  grpc::ServerUnaryReactor* SubmitJob(grpc::CallbackServerContext* ctx,
                                      const v1::SubmitJobRequest* req,
                                      v1::SubmitJobResponse* resp) override;
  grpc::ServerUnaryReactor* GetJob(grpc::CallbackServerContext* ctx, const v1::GetJobRequest* req,
                                   v1::GetJobResponse* resp) override;
  grpc::ServerUnaryReactor* ListJobs(grpc::CallbackServerContext* ctx,
                                     const v1::ListJobsRequest* req,
                                     v1::ListJobsResponse* resp) override;
  grpc::ServerUnaryReactor* CancelJob(grpc::CallbackServerContext* ctx,
                                      const v1::CancelJobRequest* req,
                                      v1::CancelJobResponse* resp) override;
  grpc::ServerWriteReactor<v1::WatchJobResponse>* WatchJob(grpc::CallbackServerContext* ctx,
                                                           const v1::WatchJobRequest* req) override;
  grpc::ServerWriteReactor<v1::FetchResultResponse>* FetchResult(
      grpc::CallbackServerContext* ctx, const v1::FetchResultRequest* req) override;
  grpc::ServerReadReactor<v1::UploadAssetRequest>* UploadAsset(
      grpc::CallbackServerContext* ctx, v1::UploadAssetResponse* resp) override;
  grpc::ServerUnaryReactor* PinJob(grpc::CallbackServerContext* ctx, const v1::PinJobRequest* req,
                                   v1::PinJobResponse* resp) override;
  grpc::ServerUnaryReactor* DeleteJob(grpc::CallbackServerContext* ctx,
                                      const v1::DeleteJobRequest* req,
                                      v1::DeleteJobResponse* resp) override;
  grpc::ServerUnaryReactor* PokeJob(grpc::CallbackServerContext* ctx,
                                    const v1::PokeJobRequest* req,
                                    v1::PokeJobResponse* resp) override;
  grpc::ServerUnaryReactor* SetJobPriority(grpc::CallbackServerContext* ctx,
                                           const v1::SetJobPriorityRequest* req,
                                           v1::SetJobPriorityResponse* resp) override;
  grpc::ServerUnaryReactor* RetryJob(grpc::CallbackServerContext* ctx,
                                     const v1::RetryJobRequest* req,
                                     v1::RetryJobResponse* resp) override;
  grpc::ServerUnaryReactor* ListWorkers(grpc::CallbackServerContext* ctx,
                                        const v1::ListWorkersRequest* req,
                                        v1::ListWorkersResponse* resp) override;
  grpc::ServerUnaryReactor* GetJobEvents(grpc::CallbackServerContext* ctx,
                                         const v1::GetJobEventsRequest* req,
                                         v1::GetJobEventsResponse* resp) override;

 private:
  // Validates and stores one submission (runs on the admission thread).
  // With `retry_of`: a retry of that job (RetryJob), never from the cache.
  grpc::Status Admit(const Principal& caller, const v1::SubmitJobRequest& req,
                     v1::SubmitJobResponse& resp, const JobRecord* retry_of = nullptr);
  // RetryJob's body (runs on the executor).
  grpc::Status Retry(const Principal& caller, const std::string& job_id,
                     v1::RetryJobResponse& resp);
  // DeleteJob's body (runs on the executor).
  grpc::Status Delete(const Principal& caller, const std::string& job_id,
                      v1::DeleteJobResponse& resp);
  // Answers a unary call with `work`'s status, run on the blocking executor.
  // Only after the caller is authenticated; an unknown caller is answered
  // UNAUTHENTICATED at once.
  grpc::ServerUnaryReactor* OffThread(grpc::CallbackServerContext* ctx,
                                      std::function<grpc::Status(const Principal&)> work);
  // PokeJob's body (runs on the executor).
  grpc::Status Poke(const Principal& caller, const v1::PokeJobRequest& req,
                    v1::PokeJobResponse& resp);
  // CancelJob's body (runs on the executor).
  grpc::Status Cancel(const Principal& caller, const std::string& job_id, v1::Job& out);
  // Waits up to cancel_wait_ms_ for `job_id` to leave RUNNING; its view then.
  std::shared_ptr<const v1::Job> AwaitStop(const std::string& job_id);

  JobStore* store_;
  ResultStore* results_;
  AssetStore* assets_;
  JobHub* hub_;
  WorkerPool* pool_;
  spec::Limits limits_;
  int64_t cancel_wait_ms_ = 5000;
  TokenTable tokens_;
  Quotas quotas_;
  int64_t retention_ms_ = 0;
  uint64_t auto_shard_iterations_ = 0;
  int64_t lease_ms_ = 30'000;
  // The result cache (docs/result_cache.md): fills `nj` as a copy of the
  // newest finished job with its spec hash, if any. False on a miss.
  bool AnswerFromCache(NewJob& nj);
  // A sharded parent's view with its shards' progress summed.
  void AddShardProgress(const JobRecord& rec, v1::Job& view);
  // Cancels waiting for their job to stop; bounded so they can never hold
  // every executor thread and starve reads.
  std::atomic<int> cancel_waits_{0};
  // Last: drained before the members their tasks use go.
  BlockingExecutor blocking_{4, 512};
  Admission admission_;
};

/// Maps an absl::Status onto a grpc::Status with the same code and message.
grpc::Status ToGrpc(const absl::Status& s);

}  // namespace nimbus::server
