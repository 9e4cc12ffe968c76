// @brief The server's Prometheus metrics (docs/operator_guide.md
// "Metrics"): counters fed by the gRPC interceptor and the HTTP port,
// gauges of the job store read at scrape time, and the durations of the
// job store's calls (TimedJobStore). Served as text by the HTTP port's
// /metrics; prometheus-cpp core only (no exposer of its own).
#pragma once

#include <cstdint>
#include <memory>
#include <string>

#include "server/timed_job_store.h"

namespace grpc::experimental {
class ServerInterceptorFactoryInterface;
}

namespace nimbus::server {

/// Bands of nimbus_queue_depth's `priority_band` label, by job priority
/// (kMinPriority..kMaxPriority): low 0-33, normal 34-66, high 67-100.
const char* PriorityBand(int priority);

class ServiceMetrics : public StoreCallObserver {
 public:
  /// `store` (its List) is read at each scrape; `local_workers` is this replica's
  /// worker count (nimbus_workers_alive).
  ServiceMetrics(JobQueue* store, int local_workers);
  ~ServiceMetrics() override;

  /// Counts every gRPC call by method and status code (and SubmitJob's
  /// refusals by code); give it to the ServerBuilder.
  std::unique_ptr<grpc::experimental::ServerInterceptorFactoryInterface> InterceptorFactory();
  /// One finished gRPC call: `method` is gRPC's "/package.Service/Method".
  void CountGrpcCall(const std::string& method, int code, double seconds);
  void AddPreviewBytes(uint64_t bytes);
  void AddDownloadBytes(uint64_t bytes);
  /// One job store call (a TimedJobStore's observer):
  /// nimbus_store_call_duration_seconds{call}.
  void ObserveStoreCall(StoreCall call, double seconds) override;
  /// Refreshes the job gauges from the store and returns every metric in
  /// Prometheus' text format (version 0.0.4). Safe from several threads.
  std::string Scrape();

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace nimbus::server
