#include "server/http_server.h"

#include <grpcpp/generic/generic_stub.h>
#include <spdlog/spdlog.h>
#include <unistd.h>

#include <future>
#include <thread>

#include "absl/strings/str_cat.h"
#include "server/http_internal.h"

#ifndef NIMBUS_CONSOLE_SOURCE_DIR
#define NIMBUS_CONSOLE_SOURCE_DIR ""
#endif

namespace nimbus::server {

struct HttpServer::Impl {
  std::unique_ptr<httplib::Server> server;
  std::shared_ptr<http::ApiState> api;
  std::thread thread;
  int port = 0;
  std::string address;
  bool stopped = false;
};

HttpServer::HttpServer(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
HttpServer::~HttpServer() { Stop(); }
int HttpServer::port() const { return impl_->port; }
std::string HttpServer::address() const { return impl_->address; }

void HttpServer::Stop() {
  if (impl_->stopped) return;
  impl_->stopped = true;
  impl_->server->stop();
  if (impl_->thread.joinable()) impl_->thread.join();
}

std::filesystem::path DefaultConsoleDir() {
  std::error_code ec;
  const std::filesystem::path exe = std::filesystem::read_symlink("/proc/self/exe", ec);
  if (!ec) {
    const auto installed = exe.parent_path().parent_path() / "share" / "nimbus" / "console";
    if (std::filesystem::is_regular_file(installed / "index.html", ec)) return installed;
  }
  return NIMBUS_CONSOLE_SOURCE_DIR;
}

namespace {

absl::StatusOr<std::unique_ptr<httplib::Server>> MakeServer(const HttpOptions& o) {
  if (o.tls_cert_file.empty()) return std::make_unique<httplib::Server>();
  auto server = std::make_unique<httplib::SSLServer>(
      o.tls_cert_file.c_str(), o.tls_key_file.c_str(),
      o.tls_client_ca_file.empty() ? nullptr : o.tls_client_ca_file.c_str());
  if (!server->is_valid())
    return absl::InvalidArgumentError(absl::StrCat("--http: cannot serve HTTPS with --tls-cert ",
                                                   o.tls_cert_file, " and --tls-key ",
                                                   o.tls_key_file));
  return server;
}

// Headers on every answer: the console runs only its own scripts, talks
// only to this origin and may not be framed.
void SetSecurityHeaders(httplib::Response& res) {
  res.set_header("X-Content-Type-Options", "nosniff");
  res.set_header("Referrer-Policy", "no-referrer");
  res.set_header("Content-Security-Policy",
                 "default-src 'self'; img-src 'self' blob: data:; script-src 'self'; "
                 "style-src 'self'; connect-src 'self'; object-src 'none'; "
                 "frame-ancestors 'none'; base-uri 'none'; form-action 'none'");
}

// grpc.health.v1.Health/Check of `service` ("" for the whole server),
// asked through `channel` with the messages encoded by hand (field 1 of
// the request is the service name, field 1 of the answer the status):
// "SERVING", "NOT_SERVING", "SERVICE_UNKNOWN" or "UNKNOWN".
std::string HealthStatus(std::shared_ptr<grpc::Channel> channel, const std::string& service) {
  std::string request;
  if (!service.empty())
    request = absl::StrCat("\x0a", std::string(1, char(service.size())), service);
  grpc::Slice slice(request);
  grpc::ByteBuffer in(&slice, 1), out;
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(5));
  grpc::GenericStub stub(std::move(channel));
  std::promise<grpc::Status> done;
  stub.UnaryCall(&ctx, "/grpc.health.v1.Health/Check", grpc::StubOptions(), &in, &out,
                 [&done](grpc::Status st) { done.set_value(st); });
  grpc::Status st = done.get_future().get();
  std::vector<grpc::Slice> slices;
  if (!st.ok() || !out.Dump(&slices).ok()) return "UNKNOWN";
  std::string bytes;
  for (const grpc::Slice& s : slices)
    bytes.append(reinterpret_cast<const char*>(s.begin()), s.size());
  const int status = bytes.size() == 2 && bytes[0] == 0x08 ? bytes[1] : 0;
  switch (status) {
    case 1:
      return "SERVING";
    case 2:
      return "NOT_SERVING";
    case 3:
      return "SERVICE_UNKNOWN";
    default:
      return "UNKNOWN";
  }
}

void RegisterOperatorRoutes(httplib::Server& server, ServiceMetrics* metrics,
                            std::shared_ptr<grpc::Channel> channel) {
  server.Get("/metrics", [metrics](const httplib::Request&, httplib::Response& res) {
    res.set_content(metrics->Scrape(), "text/plain; version=0.0.4; charset=utf-8");
  });
  // grpc.health.v1 as it stands: the server overall (liveness), and
  // nimbus.v1.NimbusService (readiness: NOT_SERVING while the job store
  // does not answer and once shutdown has begun).
  for (const auto& [path, service] : {std::pair<std::string, std::string>{"/healthz", ""},
                                      {"/readyz", "nimbus.v1.NimbusService"}})
    server.Get(path, [channel, service = service](const httplib::Request&, httplib::Response& res) {
      const std::string status = HealthStatus(channel, service);
      res.status = status == "SERVING" ? 200 : 503;
      res.set_content(absl::StrCat("{\"status\":\"", status, "\"}\n"), "application/json");
    });
}

}  // namespace

absl::StatusOr<std::unique_ptr<HttpServer>> HttpServer::Start(
    const HttpOptions& options, std::shared_ptr<grpc::Channel> channel, ServiceMetrics* metrics) {
  auto server = MakeServer(options);
  if (!server.ok()) return server.status();
  auto impl = std::make_unique<Impl>();
  impl->server = std::move(*server);
  httplib::Server& s = *impl->server;
  const int threads = std::max(options.threads, options.max_streams + 8);
  s.new_task_queue = [threads] { return new httplib::ThreadPool(size_t(threads)); };
  s.set_payload_max_length(options.max_body_bytes);
  s.set_post_routing_handler(
      [](const httplib::Request&, httplib::Response& res) { SetSecurityHeaders(res); });
  impl->api = std::make_shared<http::ApiState>();
  impl->api->channel = channel;
  impl->api->stub = v1::NimbusService::NewStub(channel);
  impl->api->metrics = metrics;
  impl->api->max_streams = options.max_streams;
  http::RegisterApi(s, impl->api);
  RegisterOperatorRoutes(s, metrics, channel);
  std::error_code ec;
  if (!options.console_dir.empty() &&
      std::filesystem::is_regular_file(options.console_dir / "index.html", ec))
    s.set_mount_point("/", options.console_dir.string());
  else
    spdlog::warn("event=no_console dir=\"{}\"", options.console_dir.string());

  const size_t colon = options.listen.rfind(':');
  if (colon == std::string::npos)
    return absl::InvalidArgumentError(absl::StrCat("--http ", options.listen, ": not host:port"));
  std::string host = options.listen.substr(0, colon);
  if (host.size() > 1 && host.front() == '[' && host.back() == ']')
    host = host.substr(1, host.size() - 2);
  int port = 0;
  try {
    port = std::stoi(options.listen.substr(colon + 1));
  } catch (...) {
    return absl::InvalidArgumentError(absl::StrCat("--http ", options.listen, ": bad port"));
  }
  impl->port = port == 0 ? s.bind_to_any_port(host) : (s.bind_to_port(host, port) ? port : -1);
  if (impl->port <= 0)
    return absl::UnavailableError(absl::StrCat("--http: cannot listen on ", options.listen));
  impl->address = absl::StrCat(options.listen.substr(0, colon), ":", impl->port);
  impl->thread = std::thread([&s] { s.listen_after_bind(); });
  spdlog::info("event=http_started listen={} tls={} console={}", impl->address,
               !options.tls_cert_file.empty(), options.console_dir.string());
  return std::unique_ptr<HttpServer>(new HttpServer(std::move(impl)));
}

}  // namespace nimbus::server
