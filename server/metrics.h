// @brief The server's Prometheus metrics (docs/operator_guide.md
// "Metrics"): counters fed by the gRPC interceptor and the HTTP port, and
// gauges of the job store read at scrape time. Served as text by the HTTP
// port's /metrics; prometheus-cpp core only (no exposer of its own).
#pragma once

#include <cstdint>
#include <memory>
#include <string>

namespace grpc::experimental {
class ServerInterceptorFactoryInterface;
}

namespace nimbus::server {

class JobQueue;

class ServiceMetrics {
 public:
  /// `store` (its List) is read at each scrape; `local_workers` is this replica's
  /// worker count (nimbus_workers_alive).
  ServiceMetrics(JobQueue* store, int local_workers);
  ~ServiceMetrics();

  /// Counts every gRPC call by method and status code (and SubmitJob's
  /// refusals by code); give it to the ServerBuilder.
  std::unique_ptr<grpc::experimental::ServerInterceptorFactoryInterface> InterceptorFactory();
  /// One finished gRPC call: `method` is gRPC's "/package.Service/Method".
  void CountGrpcCall(const std::string& method, int code, double seconds);
  void AddPreviewBytes(uint64_t bytes);
  void AddDownloadBytes(uint64_t bytes);
  /// Refreshes the job gauges from the store and returns every metric in
  /// Prometheus' text format (version 0.0.4). Safe from several threads.
  std::string Scrape();

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace nimbus::server
