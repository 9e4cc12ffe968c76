#include "server/server.h"

#include <grpcpp/ext/proto_server_reflection_plugin.h>
#include <grpcpp/grpcpp.h>
#include <grpcpp/health_check_service_interface.h>
#include <spdlog/spdlog.h>
#include <unistd.h>

#include <cstring>
#include <fstream>
#include <optional>
#include <sstream>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "server/asset_store.h"
#include "server/auth.h"
#include "server/data_dir_lock.h"
#include "server/http_server.h"
#include "server/job_hub.h"
#include "server/job_store.h"
#include "server/job_view.h"
#include "server/metrics.h"
#include "server/nimbus_service.h"
#include "server/parse_errors.h"
#include "server/result_audit.h"
#include "server/result_export.h"
#include "server/result_store.h"
#include "server/retention.h"
#include "server/store_probe.h"
#include "server/timed_job_store.h"
#include "server/tls_files.h"
#include "server/worker_pool.h"

namespace nimbus::server {

struct NimbusServer::Impl {
  std::optional<DataDirLock> data_dir_lock;  // first member: released last
  std::unique_ptr<JobStore> store;  // a TimedJobStore reporting to `metrics`
  // Before everything that calls the store: destroyed after all of it.
  std::unique_ptr<ServiceMetrics> metrics;
  std::unique_ptr<ResultStore> results;
  std::unique_ptr<AssetStore> assets;
  JobHub hub;
  std::unique_ptr<WorkerPool> pool;
  std::unique_ptr<NimbusServiceImpl> service;
  std::unique_ptr<RetentionSweeper> sweeper;
  std::unique_ptr<grpc::Server> server;
  std::unique_ptr<StoreProbe> store_probe;  // destroyed before the server and store
  std::unique_ptr<HttpServer> http;
  int port = 0;
  std::string address;
  std::mutex mu;
  bool shut_down = false;
  int64_t drain_ms = 2'000;
  int64_t retention_ms = 0;
};

NimbusServer::NimbusServer(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}

std::string DefaultReplicaId() {
  char host[256] = {};
  if (::gethostname(host, sizeof(host) - 1) != 0 || host[0] == '\0') std::strcpy(host, "nimbusd");
  return absl::StrCat(host, "-", ::getpid());
}

namespace {

absl::StatusOr<std::string> ReadPem(const std::string& flag, const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream text;
  text << in.rdbuf();
  if (!in || text.str().empty())
    return absl::InvalidArgumentError(absl::StrCat(flag, " ", path, ": cannot read the file"));
  return text.str();
}

// TLS when a certificate is given (mutual with a client CA), else plaintext.
absl::StatusOr<std::shared_ptr<grpc::ServerCredentials>> ListenCredentials(const ServerOptions& o) {
  if (o.tls_cert_file.empty() != o.tls_key_file.empty())
    return absl::InvalidArgumentError("--tls-cert and --tls-key go together");
  if (o.tls_cert_file.empty()) {
    if (!o.tls_client_ca_file.empty())
      return absl::InvalidArgumentError("--tls-client-ca needs --tls-cert and --tls-key");
    return grpc::InsecureServerCredentials();
  }
  grpc::SslServerCredentialsOptions ssl;
  grpc::SslServerCredentialsOptions::PemKeyCertPair pair;
  auto cert = ReadPem("--tls-cert", o.tls_cert_file);
  if (!cert.ok()) return cert.status();
  auto key = ReadPem("--tls-key", o.tls_key_file);
  if (!key.ok()) return key.status();
  if (auto st = CheckTlsKeyPair({"--tls-cert", o.tls_cert_file, *cert},
                                {"--tls-key", o.tls_key_file, *key});
      !st.ok())
    return st;
  pair.cert_chain = std::move(*cert);
  pair.private_key = std::move(*key);
  ssl.pem_key_cert_pairs.push_back(std::move(pair));
  if (!o.tls_client_ca_file.empty()) {
    auto ca = ReadPem("--tls-client-ca", o.tls_client_ca_file);
    if (!ca.ok()) return ca.status();
    if (auto st = CheckPemCertificates({"--tls-client-ca", o.tls_client_ca_file, *ca}); !st.ok())
      return st;
    ssl.pem_root_certs = std::move(*ca);
    ssl.client_certificate_request = GRPC_SSL_REQUEST_AND_REQUIRE_CLIENT_CERTIFICATE_AND_VERIFY;
  }
  return grpc::SslServerCredentials(ssl);
}

// The tokens of --auth-tokens and NIMBUS_AUTH_TOKENS; empty when neither.
absl::StatusOr<TokenTable> LoadTokens(const ServerOptions& o) {
  if (o.auth_tokens_file.empty() && o.auth_tokens_text.empty()) return TokenTable();
  std::string text;
  if (!o.auth_tokens_file.empty()) {
    auto file = ReadTokensFile(o.auth_tokens_file);
    if (!file.ok()) return file.status();
    text = *file + "\n";
  }
  text += o.auth_tokens_text;
  std::string source;
  if (!o.auth_tokens_file.empty()) source = absl::StrCat("--auth-tokens ", o.auth_tokens_file);
  if (!o.auth_tokens_text.empty())
    source = source.empty() ? "NIMBUS_AUTH_TOKENS" : source + " with NIMBUS_AUTH_TOKENS";
  return TokenTable::Parse(text, source);
}

// Beyond loopback, a server without tokens would hand every job to anyone
// who can reach the port.
absl::Status CheckExposure(const std::string& listen, const ServerOptions& o,
                           const TokenTable& tokens) {
  if (listen.empty() || !tokens.empty() || o.insecure || IsLoopbackListen(listen))
    return absl::OkStatus();
  return absl::FailedPreconditionError(absl::StrCat(
      "refusing to listen on ", listen,
      " without authentication: anyone who reaches it could read and cancel every job. Give "
      "--auth-tokens FILE (with --tls-cert/--tls-key), listen on 127.0.0.1, or pass --insecure"));
}

// Result files no job owns mean the job store lost jobs (a damaged or
// replaced jobs.db, a store pointed at the wrong database): say so at
// start, naming a few, rather than serve an empty queue in silence.
void ReportUnknownResults(JobStore& store, const std::filesystem::path& results_dir) {
  constexpr size_t kMaxChecked = 100'000;
  auto unknown = FindUnknownResults(store, results_dir, kMaxChecked);
  if (!unknown.ok()) {
    spdlog::warn("event=result_audit_failed error=\"{}\"", unknown.status().ToString());
    return;
  }
  if (unknown->ids.empty()) return;
  const size_t shown = std::min<size_t>(unknown->ids.size(), 5);
  spdlog::warn(
      "event=unknown_results count={} checked={} dir={} first=\"{}\" hint=\"result files whose "
      "jobs this job store does not have: was jobs.db replaced or damaged? They are kept, not "
      "served; restore the store from a backup or delete them\"",
      unknown->ids.size(), unknown->checked, results_dir.string(),
      absl::StrJoin(unknown->ids.begin(), unknown->ids.begin() + shown, " "));
}

// Where results go: --results-dir, or the data dir's own folder.
std::filesystem::path ResultsDir(const ServerOptions& options) {
  return options.results_dir.empty() ? options.data_dir / "results" : options.results_dir;
}

// This process is the only user of its SQLite store, so anything still
// RUNNING belonged to a process that died: run it again. Not fatal: on a
// full disk the server must still start and serve reads, and a RUNNING job
// whose lease lapsed is claimed again anyway. With a shared store, RUNNING
// jobs may be other replicas' live claims: only lease expiry hands them on.
void RecoverAtStart(JobStore& store, ResultStore& results, const ServerOptions& options) {
  const bool shared_store = !options.store_url.empty();
  auto requeued = shared_store ? absl::StatusOr<int>(0) : store.RequeueRunning();
  if (!requeued.ok())
    spdlog::error("event=requeue_failed error=\"{}\"", requeued.status().ToString());
  else if (*requeued > 0)
    spdlog::warn("event=recovered requeued_jobs={}", *requeued);
  ReportUnknownResults(store, ResultsDir(options));
  if (auto space = results.CheckFreeSpace(); !space.ok())
    spdlog::warn("event=low_disk error=\"{}\"", std::string(space.message()));
}

absl::StatusOr<std::unique_ptr<HttpServer>> StartHttp(grpc::Server& server, ServiceMetrics* metrics,
                                                      const ServerOptions& o) {
  HttpOptions http;
  http.listen = o.http_listen;
  http.tls_cert_file = o.tls_cert_file;
  http.tls_key_file = o.tls_key_file;
  http.tls_client_ca_file = o.tls_client_ca_file;
  http.console_dir = o.console_dir.empty() ? DefaultConsoleDir() : o.console_dir;
  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(64 << 20);
  return HttpServer::Start(http, server.InProcessChannel(args), metrics);
}

}  // namespace

// Readiness follows the shared store: the service's health status is
// NOT_SERVING while the store does not answer, SERVING again once it does.
// The overall status (liveness) stays SERVING, so an orchestrator does not
// restart every replica during a database outage.
void NimbusServer::FollowStoreHealth(Impl& impl) {
  grpc::HealthCheckServiceInterface* health = impl.server->GetHealthCheckService();
  if (health == nullptr) return;
  JobStore* store = impl.store.get();
  constexpr int64_t kProbeMs = 1'000;
  impl.store_probe = std::make_unique<StoreProbe>(
      // A job id that never exists: NOT_FOUND is the store's answer.
      [store] { return store->Get("~store-probe").status(); },
      [health](bool up) {
        health->SetServingStatus("nimbus.v1.NimbusService", up);
        if (up) {
          spdlog::info("event=store_reachable");
        } else {
          spdlog::warn("event=store_unreachable");
        }
      },
      kProbeMs);
  impl.store_probe->Start();
}

// The shared store's change feed: a submit on any replica wakes an idle
// worker here at once, and watchers here of a job another replica runs get
// its state and progress (as of its last heartbeat).
void NimbusServer::FollowOtherReplicas(Impl& impl) {
  JobStore* store = impl.store.get();
  JobHub* hub = &impl.hub;
  WorkerPool* pool = impl.pool.get();
  store->SetChangeListener([store, hub, pool](const JobChange& change) {
    if (change.claimable) pool->Wake();
    // A job running here publishes richer views itself.
    const std::string& id = change.job_id;
    if (id.empty() || pool->IsRunning(id)) return;
    // Unwatched: drop whatever its last watcher here left in the hub.
    if (!hub->Watched(id)) return hub->Forget(id);
    const std::vector<JobHub::PreviewWant> wants = hub->WantedPreviews(id);
    if (change.preview) {
      for (const JobHub::PreviewWant& want : wants) {
        auto bytes = store->LatestPreview(id, want.resolution);
        v1::Preview preview;
        if (bytes.ok() && preview.ParseFromString(*bytes))
          hub->PublishPreview(id, want.resolution, std::move(preview));
      }
      return;
    }
    auto record = store->Get(id);
    if (!record.ok()) return;
    // Each heartbeat of the running replica renews our watchers' wishes.
    if (!wants.empty() && record->state == JobState::kRunning) {
      std::vector<PreviewWish> wishes;
      for (const JobHub::PreviewWant& w : wants)
        wishes.push_back({w.resolution, w.interval_seconds});
      (void)store->WishPreviews(id, wishes, NowMs() + 10'000);
    }
    hub->PublishJob(ToProto(*record, false));
    if (IsTerminal(record->state)) hub->Forget(id);
  });
}

NimbusServer::~NimbusServer() { Shutdown(); }

absl::Status NimbusServer::OpenStores(Impl& impl, const ServerOptions& options,
                                      const std::string& replica_id) {
  std::error_code ec;
  std::filesystem::create_directories(options.data_dir, ec);
  if (ec)
    return absl::InvalidArgumentError(
        absl::StrCat("--data-dir ", options.data_dir.string(), ": ", ec.message()));
  // Replicas: the job store, result folder and replica id (see server.h).
  const bool shared_store = !options.store_url.empty();
  if (!shared_store) {
    auto lock = DataDirLock::Acquire(options.data_dir);
    if (!lock.ok()) return lock.status();
    impl.data_dir_lock.emplace(std::move(*lock));
  }
  auto store = shared_store ? OpenPostgresJobStore(options.store_url)
                            : OpenSqliteJobStore((options.data_dir / "jobs.db").string());
  if (!store.ok()) return store.status();
  auto timed = std::make_unique<TimedJobStore>(std::move(*store));
  impl.metrics = std::make_unique<ServiceMetrics>(timed.get(), options.workers);
  timed->set_observer(impl.metrics.get());
  impl.store = std::move(timed);
  const std::filesystem::path results_dir = ResultsDir(options);
  // A shared store means other replicas may write the same folder: each
  // attempt writes its own scratch file and reads check the content hash.
  auto results = shared_store || !options.results_dir.empty()
                     ? OpenSharedResultStore(results_dir, replica_id,
                                             options.min_free_disk_mib << 20)
                     : OpenLocalResultStore(results_dir, options.min_free_disk_mib << 20);
  if (!results.ok()) return results.status();
  impl.results = std::move(*results);
  // Replicas sharing results share uploaded assets too: a job may run on
  // another replica than the one its mesh was uploaded to.
  auto assets = AssetStore::Open(options.results_dir.empty() ? options.data_dir / "assets"
                                                             : results_dir / "assets");
  if (!assets.ok()) return assets.status();
  impl.assets = std::move(*assets);
  return absl::OkStatus();
}

void NimbusServer::MakeService(Impl& impl, const ServerOptions& options,
                               const std::string& replica_id, TokenTable tokens) {
  // Specs name uploaded assets by hash; only an in-process server (the CLI's
  // own) may also read local paths, since its client is this process.
  spec::Limits limits = options.limits;
  limits.asset_dir = impl.assets->dir();
  limits.allow_local_paths = options.listen.empty();
  WorkerOptions wo;
  wo.workers = options.workers;
  wo.threads_per_job = options.threads_per_job;
  wo.limits = limits;
  wo.lease_ms = options.lease_ms;
  wo.heartbeat_ms = options.heartbeat_ms;
  wo.max_attempts = options.max_attempts;
  wo.instance_id = replica_id;
  impl.pool = std::make_unique<WorkerPool>(impl.store.get(), impl.results.get(), &impl.hub, wo);
  impl.service = std::make_unique<NimbusServiceImpl>(
      impl.store.get(), impl.results.get(), impl.assets.get(), &impl.hub, impl.pool.get(), limits);
  impl.service->set_cancel_wait_ms(options.cancel_wait_ms);
  impl.service->set_auto_shard_iterations(options.auto_shard_iterations);
  impl.service->set_lease_ms(options.lease_ms);
  impl.service->set_security(
      std::move(tokens),
      Quotas{options.quota_jobs, options.quota_asset_bytes, options.quota_result_bytes},
      options.retention_ms);
  impl.retention_ms = options.retention_ms;
  impl.sweeper = std::make_unique<RetentionSweeper>(impl.store.get(), impl.results.get(),
                                                    impl.assets.get(), options.retention_ms,
                                                    SweepIntervalMs(options.retention_ms));
  impl.sweeper->set_event_log(impl.store.get());
}

absl::Status NimbusServer::Listen(Impl& impl, const ServerOptions& options,
                                  const std::shared_ptr<grpc::ServerCredentials>& credentials) {
  grpc::EnableDefaultHealthCheckService(true);
  grpc::reflection::InitProtoReflectionServerBuilderPlugin();
  grpc::ServerBuilder builder;
  if (!options.listen.empty()) builder.AddListeningPort(options.listen, credentials, &impl.port);
  builder.RegisterService(impl.service.get());
  auto interceptors = UndecodableRequestInterceptors();
  interceptors.push_back(impl.metrics->InterceptorFactory());
  builder.experimental().SetInterceptorCreators(std::move(interceptors));
  // Previews and result chunks are a few MiB at most.
  builder.SetMaxSendMessageSize(64 << 20);
  builder.SetMaxReceiveMessageSize(64 << 20);
  impl.server = builder.BuildAndStart();
  if (!impl.server || (!options.listen.empty() && impl.port == 0))
    return absl::UnavailableError(absl::StrCat("cannot listen on ", options.listen));
  if (auto* health = impl.server->GetHealthCheckService()) {
    health->SetServingStatus("nimbus.v1.NimbusService", true);
    health->SetServingStatus(true);
  }
  if (!options.http_listen.empty()) {
    auto http = StartHttp(*impl.server, impl.metrics.get(), options);
    if (!http.ok()) return http.status();
    impl.http = std::move(*http);
  }
  if (impl.port > 0) {
    // "host:0" asks for any free port; report the one we got.
    const size_t colon = options.listen.rfind(':');
    impl.address = absl::StrCat(options.listen.substr(0, colon), ":", impl.port);
  }
  return absl::OkStatus();
}

absl::StatusOr<std::unique_ptr<NimbusServer>> NimbusServer::Start(const ServerOptions& options) {
  auto tokens = LoadTokens(options);
  if (!tokens.ok()) return tokens.status();
  for (const std::string& listen : {options.listen, options.http_listen})
    if (auto st = CheckExposure(listen, options, *tokens); !st.ok()) return st;
  auto credentials = ListenCredentials(options);
  if (!credentials.ok()) return credentials.status();
  auto impl = std::make_unique<Impl>();
  impl->drain_ms = options.drain_ms;
  const std::string replica_id =
      options.replica_id.empty() ? DefaultReplicaId() : options.replica_id;
  if (auto st = OpenStores(*impl, options, replica_id); !st.ok()) return st;
  RecoverAtStart(*impl->store, *impl->results, options);
  const size_t principals = tokens->size();
  MakeService(*impl, options, replica_id, std::move(*tokens));
  if (auto st = Listen(*impl, options, *credentials); !st.ok()) return st;
  const bool shared_store = !options.store_url.empty();
  if (shared_store) {
    FollowOtherReplicas(*impl);
    FollowStoreHealth(*impl);
  }
  impl->pool->Start();
  impl->sweeper->Start();
  spdlog::info(
      "event=started listen={} port={} data_dir={} store={} replica={} workers={} "
      "threads_per_job={} tls={} mtls={} auth_tokens={} retention_s={}",
      options.listen, impl->port, options.data_dir.string(), shared_store ? "postgresql" : "sqlite",
      replica_id, options.workers, impl->pool->threads_per_job(), !options.tls_cert_file.empty(),
      !options.tls_client_ca_file.empty(), principals, options.retention_ms / 1000);
  return std::unique_ptr<NimbusServer>(new NimbusServer(std::move(impl)));
}

int NimbusServer::port() const { return impl_->port; }

std::string NimbusServer::address() const { return impl_->address; }

int NimbusServer::http_port() const { return impl_->http ? impl_->http->port() : 0; }

std::shared_ptr<grpc::Channel> NimbusServer::InProcessChannel() {
  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(64 << 20);
  return impl_->server->InProcessChannel(args);
}

absl::Status NimbusServer::ExportResult(const std::string& job_id,
                                       const std::filesystem::path& path) {
  return server::ExportResult(*impl_->store, *impl_->results, job_id, path, impl_->retention_ms);
}

void NimbusServer::Wait() { impl_->server->Wait(); }

void NimbusServer::Shutdown() {
  {
    std::lock_guard<std::mutex> lock(impl_->mu);
    if (impl_->shut_down) return;
    impl_->shut_down = true;
  }
  if (impl_->store_probe) impl_->store_probe->Stop();
  if (auto* health = impl_->server->GetHealthCheckService()) health->SetServingStatus(false);
  // Stop workers first so watchers see jobs go back to the queue, then
  // close the streams.
  // The feed's listener uses the pool and the hub: stop it first.
  impl_->store->SetChangeListener(nullptr);
  impl_->pool->Stop();
  impl_->sweeper->Stop();
  impl_->server->Shutdown(std::chrono::system_clock::now() +
                          std::chrono::milliseconds(impl_->drain_ms));
  // After the gRPC server: its shutdown ends the HTTP port's open streams.
  if (impl_->http) impl_->http->Stop();
  spdlog::info("event=stopped");
}

}  // namespace nimbus::server
