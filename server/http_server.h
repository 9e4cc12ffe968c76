// @brief nimbusd's HTTP port (--http): the JSON API under /api/v1/
// (docs/http_api.md), the console's static files, /metrics, /healthz and
// /readyz, on cpp-httplib. Every API call goes through the gRPC service's
// in-process channel with the caller's Authorization header as gRPC
// metadata, so tokens, ownership (another owner's job is 404), admission
// and validation are the gRPC service's own and cannot drift from it.
#pragma once

#include <filesystem>
#include <functional>
#include <memory>
#include <string>

#include "absl/status/statusor.h"

namespace grpc {
class Channel;
}

namespace nimbus::server {

class ServiceMetrics;

struct HttpOptions {
  /// host:port; port 0 picks a free one.
  std::string listen;
  /// PEM certificate chain and key: HTTPS (the gRPC port's files); with a
  /// client CA, client certificates are required as on the gRPC port.
  std::string tls_cert_file, tls_key_file, tls_client_ca_file;
  /// The console's static files; empty or missing: no console.
  std::filesystem::path console_dir;
  /// Threads serving requests; an open event stream holds one.
  int threads = 96;
  /// Event streams open at once; more are answered 503 so that the other
  /// threads stay free for ordinary calls.
  int max_streams = 64;
  /// Largest request body, bytes (413 beyond).
  size_t max_body_bytes = 8 << 20;
};

class HttpServer {
 public:
  /// Binds and starts serving. `channel` reaches the gRPC service (and its
  /// grpc.health.v1 service, which /healthz and /readyz ask).
  static absl::StatusOr<std::unique_ptr<HttpServer>> Start(const HttpOptions& options,
                                                           std::shared_ptr<grpc::Channel> channel,
                                                           ServiceMetrics* metrics);
  ~HttpServer();
  int port() const;
  /// host:port as bound.
  std::string address() const;
  /// Stops listening and waits for the request threads. Open event
  /// streams end once the gRPC server has shut down.
  void Stop();

  struct Impl;

 private:
  explicit HttpServer(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

/// The console's default folder: share/nimbus/console beside the binary's
/// bin/ folder when installed, else the source tree's server/console.
std::filesystem::path DefaultConsoleDir();

}  // namespace nimbus::server
