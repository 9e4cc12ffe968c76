// Internal to the HTTP port (http_server.cc, http_api.cc, http_preview.cc):
// the shared state of its handlers and the helpers between them.
#pragma once

#include <grpcpp/grpcpp.h>
#include <httplib.h>

#include <atomic>
#include <memory>
#include <string>

#include "absl/status/statusor.h"
#include "nimbus/v1/nimbus_service.grpc.pb.h"
#include "server/metrics.h"

namespace nimbus::server::http {

struct ApiState {
  std::shared_ptr<grpc::Channel> channel;
  std::unique_ptr<v1::NimbusService::Stub> stub;
  ServiceMetrics* metrics = nullptr;
  int max_streams = 64;
  std::atomic<int> open_streams{0};
};

/// Registers every /api/v1/ route.
void RegisterApi(httplib::Server& server, std::shared_ptr<ApiState> state);
/// The studio queue's routes (http_queue.cc): retry, priority, events and
/// workers, answered 501 while this build's service lacks the call.
void RegisterQueue(httplib::Server& server, std::shared_ptr<ApiState> state);
/// Which of "retry", "priority", "events", "workers" this build offers.
std::vector<std::string> QueueFeatures();

/// A client context carrying the request's Authorization header as gRPC
/// metadata, with a deadline `seconds` away (0: none).
std::unique_ptr<grpc::ClientContext> CallContext(const httplib::Request& req, int seconds);

/// Answers `res` with the JSON error body of a gRPC status and its HTTP code.
void SendError(httplib::Response& res, const grpc::Status& status);
/// The same for an error of the HTTP layer itself.
void SendError(httplib::Response& res, grpc::StatusCode code, const std::string& message);

/// The newest preview of `job_id` at `resolution`, waiting (bounded) for
/// one when the job runs and none has been made yet.
absl::StatusOr<v1::Preview> LatestPreview(ApiState& state, const httplib::Request& req,
                                          const std::string& job_id, uint32_t resolution);
/// A preview's density as float32 little-endian, x slowest and z fastest,
/// with its shape.
struct DensityArray {
  int nx = 0, ny = 0, nz = 0;
  std::string bytes;
};
absl::StatusOr<DensityArray> PreviewDensity(const v1::Preview& preview);
/// The preview's picture: its PNG for jobs with an image, otherwise a grey
/// PNG of the density summed along z (log-scaled).
absl::StatusOr<std::string> PreviewPng(const v1::Preview& preview);

}  // namespace nimbus::server::http
