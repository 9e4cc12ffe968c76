// A whole Nimbus server: job store, result store, worker pool and the gRPC
// service. Used by nimbusd and, in-process, by the nimbus CLI. gRPC types
// are only forward-declared here to keep this header cheap to include.
#pragma once

#include <filesystem>
#include <memory>
#include <string>

#include "absl/status/statusor.h"
#include "proto/spec_convert.h"

namespace grpc {
class Channel;
class ServerCredentials;
}

namespace nimbus::server {

class TokenTable;

/// hostname-pid: a replica name unique among live processes.
std::string DefaultReplicaId();

struct ServerOptions {
  /// host:port to listen on; empty for in-process use only.
  std::string listen = "127.0.0.1:50051";
  std::filesystem::path data_dir = "nimbus-data";
  int workers = 1;
  /// Engine threads per job; 0 = hardware threads / workers.
  int threads_per_job = 0;
  spec::Limits limits;
  int64_t lease_ms = 30'000;
  int64_t heartbeat_ms = 2'000;
  /// How long CancelJob waits for a running job to stop before answering
  /// it RUNNING with cancel_requested; 0 answers at once.
  int64_t cancel_wait_ms = 5'000;
  /// Free space the data folder keeps: below it SubmitJob refuses new jobs
  /// (RESOURCE_EXHAUSTED) so running ones can still write; 0 = no reserve.
  uint64_t min_free_disk_mib = 1024;
  /// How long Shutdown() lets open RPCs finish before cancelling them.
  /// Running jobs are interrupted at once and given back to the queue.
  int64_t drain_ms = 2'000;
  /// Claims a job gets before it fails with its last attempt's error
  /// (0: no limit): a job that cannot record its end never loops.
  uint32_t max_attempts = 3;

  // Security (docs/operator_guide.md "Security").
  /// PEM certificate chain and private key: serve TLS instead of plaintext.
  std::string tls_cert_file, tls_key_file;
  /// PEM CA bundle: require and verify client certificates (mutual TLS).
  std::string tls_client_ca_file;
  /// Tokens and principals, one `TOKEN PRINCIPAL [admin]` a line: a file
  /// (mode 600 or stricter) and/or the same lines as text (the
  /// NIMBUS_AUTH_TOKENS environment variable; ';' also separates entries).
  /// Neither: every caller is the anonymous admin.
  std::string auth_tokens_file;
  std::string auth_tokens_text;
  /// Allows listening beyond loopback without tokens.
  bool insecure = false;
  // Several replicas (docs/operator_guide.md "Several replicas").
  /// The job store: empty for SQLite in data_dir; a postgresql:// (or
  /// postgres://) URL for a queue shared by every replica given it.
  std::string store_url;
  /// This replica's name: the prefix of its workers' ids in leases (so
  /// `nimbus jobs` shows who runs what) and in its log lines. Empty:
  /// hostname-pid.
  std::string replica_id;
  /// Where results (and, when set, uploaded assets, in its `assets`
  /// folder) live; empty: data_dir/results. Replicas that share a store
  /// must share this folder too (a volume or NFS mount).
  std::filesystem::path results_dir;

  /// Per-principal limits; 0 = none.
  uint64_t quota_jobs = 0;
  uint64_t quota_asset_bytes = 0;
  uint64_t quota_result_bytes = 0;
  /// Results (and assets no queued, running or pinned job names) are
  /// deleted this long after their job ended (were uploaded); 0 = kept.
  int64_t retention_ms = 0;
  /// Jobs above this many iterations that leave JobSpec.shards at 0 are
  /// split into shards (docs/sharding.md); 0: never.
  uint64_t auto_shard_iterations = 0;

  /// host:port of the HTTP port (JSON API, console, /metrics;
  /// docs/http_api.md); empty: none. The same TLS files, tokens and
  /// loopback rule as `listen`.
  std::string http_listen;
  /// The console's static files; empty: DefaultConsoleDir() (http_server.h).
  std::filesystem::path console_dir;
};

/// @brief A running server. With its own SQLite store, jobs left RUNNING by
/// a previous process are requeued at start; with a shared store they are
/// claimed again once their lease lapses (another replica may hold them).
/// Shutdown() gives running jobs back to the queue.
class NimbusServer {
 public:
  static absl::StatusOr<std::unique_ptr<NimbusServer>> Start(const ServerOptions& options);
  ~NimbusServer();

  /// The bound port (useful with ":0"); 0 when not listening.
  int port() const;
  /// host:port as bound, e.g. "127.0.0.1:41234"; empty when not listening.
  std::string address() const;
  /// The HTTP port as bound; 0 when there is none.
  int http_port() const;
  /// A channel to this server that never leaves the process.
  std::shared_ptr<grpc::Channel> InProcessChannel();
  /// Copies a succeeded job's main result to `path` in this process, the
  /// hash checked as FetchResult's client checks it, but without streaming
  /// the bytes through gRPC messages (result_export.h). Blocks on disk I/O.
  absl::Status ExportResult(const std::string& job_id, const std::filesystem::path& path);
  /// Blocks until Shutdown() is called from another thread.
  void Wait();
  /// Interrupts running jobs (they go back to the queue), then closes the
  /// RPCs still open after `drain_ms`.
  void Shutdown();

 private:
  struct Impl;
  explicit NimbusServer(std::unique_ptr<Impl> impl);
  // The steps of Start(), in order.
  static absl::Status OpenStores(Impl& impl, const ServerOptions& options,
                                 const std::string& replica_id);
  static void MakeService(Impl& impl, const ServerOptions& options, const std::string& replica_id,
                          TokenTable tokens);
  static absl::Status Listen(Impl& impl, const ServerOptions& options,
                             const std::shared_ptr<grpc::ServerCredentials>& credentials);
  static void FollowOtherReplicas(Impl& impl);
  static void FollowStoreHealth(Impl& impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace nimbus::server
