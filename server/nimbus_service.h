// The nimbus.v1.NimbusService implementation on gRPC's callback API. Handlers
// validate, touch the store and move data; jobs run in the WorkerPool.
#pragma once

#include "nimbus/v1/nimbus_service.grpc.pb.h"
#include "proto/spec_convert.h"
#include "server/admission.h"
#include "server/asset_store.h"
#include "server/job_hub.h"
#include "server/job_store.h"
#include "server/result_store.h"
#include "server/worker_pool.h"

namespace nimbus::server {

class NimbusServiceImpl final : public v1::NimbusService::CallbackService {
 public:
  NimbusServiceImpl(JobStore* store, ResultStore* results, AssetStore* assets, JobHub* hub,
                    WorkerPool* pool, spec::Limits limits);

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

 private:
  // Validates and stores one submission (runs on the admission thread).
  grpc::Status Admit(const v1::SubmitJobRequest& req, v1::SubmitJobResponse& resp);

  JobStore* store_;
  ResultStore* results_;
  AssetStore* assets_;
  JobHub* hub_;
  WorkerPool* pool_;
  spec::Limits limits_;
  Admission admission_;  // last: drained before the members it uses go
};

/// Maps an absl::Status onto a grpc::Status with the same code and message.
grpc::Status ToGrpc(const absl::Status& s);

}  // namespace nimbus::server
