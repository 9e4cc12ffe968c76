#include "server/server.h"

#include <grpcpp/ext/proto_server_reflection_plugin.h>
#include <grpcpp/grpcpp.h>
#include <grpcpp/health_check_service_interface.h>
#include <spdlog/spdlog.h>
#include <unistd.h>

#include "absl/strings/str_cat.h"
#include "server/asset_store.h"
#include "server/job_hub.h"
#include "server/job_store.h"
#include "server/nimbus_service.h"
#include "server/result_store.h"
#include "server/worker_pool.h"

namespace nimbus::server {

struct NimbusServer::Impl {
  std::unique_ptr<JobStore> store;
  std::unique_ptr<ResultStore> results;
  std::unique_ptr<AssetStore> assets;
  JobHub hub;
  std::unique_ptr<WorkerPool> pool;
  std::unique_ptr<NimbusServiceImpl> service;
  std::unique_ptr<grpc::Server> server;
  int port = 0;
  std::string address;
  std::mutex mu;
  bool shut_down = false;
  int64_t drain_ms = 2'000;
};

NimbusServer::NimbusServer(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}

NimbusServer::~NimbusServer() { Shutdown(); }

absl::StatusOr<std::unique_ptr<NimbusServer>> NimbusServer::Start(const ServerOptions& options) {
  auto impl = std::make_unique<Impl>();
  impl->drain_ms = options.drain_ms;
  std::error_code ec;
  std::filesystem::create_directories(options.data_dir, ec);
  if (ec)
    return absl::InvalidArgumentError(
        absl::StrCat("--data-dir ", options.data_dir.string(), ": ", ec.message()));
  auto store = OpenSqliteJobStore((options.data_dir / "jobs.db").string());
  if (!store.ok()) return store.status();
  impl->store = std::move(*store);
  auto results =
      OpenLocalResultStore(options.data_dir / "results", options.min_free_disk_mib << 20);
  if (!results.ok()) return results.status();
  impl->results = std::move(*results);
  auto assets = AssetStore::Open(options.data_dir / "assets");
  if (!assets.ok()) return assets.status();
  impl->assets = std::move(*assets);
  // Specs name uploaded assets by hash; only an in-process server (the CLI's
  // own) may also read local paths, since its client is this process.
  spec::Limits limits = options.limits;
  limits.asset_dir = impl->assets->dir();
  limits.allow_local_paths = options.listen.empty();

  // This process is the only user of its SQLite store, so anything still
  // RUNNING belonged to a process that died: run it again.
  // Not fatal: on a full disk the server must still start and serve
  // reads, and a RUNNING job whose lease lapsed is claimed again anyway.
  auto requeued = impl->store->RequeueRunning();
  if (!requeued.ok())
    spdlog::error("event=requeue_failed error=\"{}\"", requeued.status().ToString());
  else if (*requeued > 0)
    spdlog::warn("event=recovered requeued_jobs={}", *requeued);
  if (auto space = impl->results->CheckFreeSpace(); !space.ok())
    spdlog::warn("event=low_disk error=\"{}\"", std::string(space.message()));

  WorkerOptions wo;
  wo.workers = options.workers;
  wo.threads_per_job = options.threads_per_job;
  wo.limits = limits;
  wo.lease_ms = options.lease_ms;
  wo.heartbeat_ms = options.heartbeat_ms;
  wo.max_attempts = options.max_attempts;
  wo.instance_id = absl::StrCat("nimbusd-", ::getpid());
  impl->pool = std::make_unique<WorkerPool>(impl->store.get(), impl->results.get(), &impl->hub, wo);
  impl->service = std::make_unique<NimbusServiceImpl>(
      impl->store.get(), impl->results.get(), impl->assets.get(), &impl->hub, impl->pool.get(),
      limits);
  impl->service->set_cancel_wait_ms(options.cancel_wait_ms);

  grpc::EnableDefaultHealthCheckService(true);
  grpc::reflection::InitProtoReflectionServerBuilderPlugin();
  grpc::ServerBuilder builder;
  if (!options.listen.empty())
    builder.AddListeningPort(options.listen, grpc::InsecureServerCredentials(), &impl->port);
  builder.RegisterService(impl->service.get());
  // Previews and result chunks are a few MiB at most.
  builder.SetMaxSendMessageSize(64 << 20);
  builder.SetMaxReceiveMessageSize(64 << 20);
  impl->server = builder.BuildAndStart();
  if (!impl->server || (!options.listen.empty() && impl->port == 0))
    return absl::UnavailableError(absl::StrCat("cannot listen on ", options.listen));
  if (auto* health = impl->server->GetHealthCheckService()) {
    health->SetServingStatus("nimbus.v1.NimbusService", true);
    health->SetServingStatus(true);
  }
  if (impl->port > 0) {
    // "host:0" asks for any free port; report the one we got.
    const size_t colon = options.listen.rfind(':');
    impl->address = absl::StrCat(options.listen.substr(0, colon), ":", impl->port);
  }
  impl->pool->Start();
  spdlog::info("event=started listen={} port={} data_dir={} workers={} threads_per_job={}",
               options.listen, impl->port, options.data_dir.string(), options.workers,
               impl->pool->threads_per_job());
  return std::unique_ptr<NimbusServer>(new NimbusServer(std::move(impl)));
}

int NimbusServer::port() const { return impl_->port; }

std::string NimbusServer::address() const { return impl_->address; }

std::shared_ptr<grpc::Channel> NimbusServer::InProcessChannel() {
  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(64 << 20);
  return impl_->server->InProcessChannel(args);
}

void NimbusServer::Wait() { impl_->server->Wait(); }

void NimbusServer::Shutdown() {
  {
    std::lock_guard<std::mutex> lock(impl_->mu);
    if (impl_->shut_down) return;
    impl_->shut_down = true;
  }
  if (auto* health = impl_->server->GetHealthCheckService()) health->SetServingStatus(false);
  // Stop workers first so watchers see jobs go back to the queue, then
  // close the streams.
  impl_->pool->Stop();
  impl_->server->Shutdown(std::chrono::system_clock::now() +
                          std::chrono::milliseconds(impl_->drain_ms));
  spdlog::info("event=stopped");
}

}  // namespace nimbus::server
