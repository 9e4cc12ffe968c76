// nimbusd: the Nimbus job server.
#include <pthread.h>
#include <spdlog/spdlog.h>

#include <CLI/CLI.hpp>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <thread>

#include "absl/strings/str_cat.h"
#include "core/base/heap_tuning.h"
#include "server/job_store.h"
#include "server/json_log.h"
#include "server/server.h"

namespace {

// Writes `port` to `path` atomically (a temporary file renamed into place),
// so a reader never sees a partly written number.
bool WritePortFile(const std::string& path, int port) {
  const std::string tmp = path + ".tmp";
  {
    std::ofstream out(tmp, std::ios::trunc);
    out << port << "\n";
    if (!out.flush()) return false;
  }
  std::error_code ec;
  std::filesystem::rename(tmp, path, ec);
  return !ec;
}

// TLS, tokens, quotas and retention (docs/operator_guide.md "Security").
void AddSecurityFlags(CLI::App& app, nimbus::server::ServerOptions& o, double& retention_hours,
                      double& retention_seconds) {
  app.add_option("--tls-cert", o.tls_cert_file, "PEM certificate chain: serve TLS");
  app.add_option("--tls-key", o.tls_key_file, "PEM private key of --tls-cert");
  app.add_option("--tls-client-ca", o.tls_client_ca_file,
                 "PEM CA bundle: require client certificates it signed (mutual TLS)");
  app.add_option("--auth-tokens", o.auth_tokens_file,
                 "file of 'TOKEN PRINCIPAL [admin]' lines (mode 600); also $NIMBUS_AUTH_TOKENS");
  app.add_flag("--insecure", o.insecure,
               "allow listening beyond loopback without tokens (anyone reaching the port may "
               "read and cancel every job)");
  app.add_option("--quota-jobs", o.quota_jobs, "queued plus running jobs per principal (0: none)")
      ->capture_default_str();
  app.add_option("--quota-asset-bytes", o.quota_asset_bytes,
                 "bytes of uploaded assets per principal (0: none)")
      ->capture_default_str();
  app.add_option("--quota-result-bytes", o.quota_result_bytes,
                 "bytes of kept results per principal; over it new jobs are refused (0: none)")
      ->capture_default_str();
  app.add_option("--retention-hours", retention_hours,
                 "delete results and unused assets this long after the job ended (0: keep)")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  app.add_option("--retention-seconds", retention_seconds,
                 "the same in seconds, for tests; wins over --retention-hours")
      ->check(CLI::NonNegativeNumber);
}

// Everything the command line sets.
struct DaemonFlags {
  nimbus::server::ServerOptions o;
  std::string data_dir = o.data_dir.string();
  double max_memory_gib = double(o.limits.max_memory_bytes) / double(1ull << 30);
  std::string log_level = "info";
  std::string log_format = "text";
  std::string port_file, http_port_file, console_dir;
  double retention_hours = 0, retention_seconds = 0;
};

// Where to serve, the limits of a job and how jobs run.
void AddServingFlags(CLI::App& app, DaemonFlags& f) {
  app.add_option("--listen", f.o.listen, "host:port to serve on (port 0: any free port)")
      ->capture_default_str();
  app.add_option("--port-file", f.port_file,
                 "write the port actually bound here once serving (useful with port 0)");
  app.add_option("--http", f.o.http_listen,
                 "host:port of the HTTP port: console, JSON API, /metrics (default: none)");
  app.add_option("--http-port-file", f.http_port_file, "write the HTTP port bound here");
  app.add_option("--console-dir", f.console_dir,
                 "the console's static files (default: the installed ones)");
  app.add_option("--data-dir", f.data_dir, "folder for the job database and results")
      ->capture_default_str();
  app.add_option("--workers", f.o.workers, "jobs run at once")
      ->capture_default_str()
      ->check(CLI::Range(1, 256));
  app.add_option("--threads-per-job", f.o.threads_per_job,
                 "engine threads per job (0: cores / workers)")
      ->capture_default_str();
  app.add_option("--lease-ms", f.o.lease_ms,
                 "how long a running job's claim lasts without a heartbeat, ms")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  app.add_option("--heartbeat-ms", f.o.heartbeat_ms, "how often running jobs renew their claim, ms")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  app.add_option("--cancel-wait-ms", f.o.cancel_wait_ms,
                 "how long CancelJob waits for a running job to stop, ms")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  app.add_option("--max-resolution", f.o.limits.max_resolution, "largest grid axis, voxels")
      ->capture_default_str();
  app.add_option("--max-voxels", f.o.limits.max_voxels, "largest grid, voxels")
      ->capture_default_str();
  app.add_option("--max-memory-gib", f.max_memory_gib, "largest estimated job memory, GiB")
      ->capture_default_str();
  app.add_option("--max-iterations", f.o.limits.max_iterations,
                 "largest iteration budget (plotted steps plus warm-up steps)")
      ->capture_default_str();
  app.add_option("--max-maps", f.o.limits.max_maps, "most maps in one IFS")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  app.add_option("--min-free-disk-mib", f.o.min_free_disk_mib,
                 "free space to keep in --data-dir: below it new jobs are refused (0: none), MiB")
      ->capture_default_str();
  app.add_option("--drain-ms", f.o.drain_ms,
                 "on SIGTERM, how long open RPCs may finish; the process exits within this "
                 "plus one second, ms")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  app.add_option("--auto-shard-iterations", f.o.auto_shard_iterations,
                 "split chaos-game jobs above this many iterations into shards of about "
                 "this size that any worker may run (docs/sharding.md); 0: never")
      ->capture_default_str();
  app.add_option("--max-attempts", f.o.max_attempts,
                 "attempts a job gets before it fails with its last error (0: no limit)")
      ->capture_default_str();
}

// Several replicas on one queue (docs/operator_guide.md "Several replicas").
void AddReplicaFlags(CLI::App& app, DaemonFlags& f) {
  app.add_option("--store", f.o.store_url,
                 "job store: a postgresql://USER@HOST/DB URL shared by replicas; default SQLite "
                 "in --data-dir (also $NIMBUS_STORE_URL)");
  app.add_option("--replica-id", f.o.replica_id,
                 "this replica's name in leases and logs (default: hostname-pid)");
  app.add_option("--results-dir", f.o.results_dir,
                 "results folder; replicas on one store must share it (default: "
                 "DATA_DIR/results)");
}

// The server's options from the flags and the environment; false (after
// a message) when they are not usable.
bool FinishOptions(DaemonFlags& f) {
  nimbus::server::ServerOptions& o = f.o;
  o.data_dir = f.data_dir;
  o.console_dir = f.console_dir;
  // A URL with a password is better kept out of the process list.
  if (o.store_url.empty())
    if (const char* env = std::getenv("NIMBUS_STORE_URL")) o.store_url = env;
  if (!o.store_url.empty() && !nimbus::server::IsPostgresUrl(o.store_url)) {
    std::fprintf(stderr, "--store: expected a postgresql:// or postgres:// URL\n");
    return false;
  }
  if (o.replica_id.empty()) o.replica_id = nimbus::server::DefaultReplicaId();
  o.retention_ms = int64_t(f.retention_seconds > 0 ? f.retention_seconds * 1000
                                                   : f.retention_hours * 3600 * 1000);
  // Tokens as text in the environment, for containers whose secrets arrive
  // that way; never logged.
  if (const char* env = std::getenv("NIMBUS_AUTH_TOKENS")) o.auth_tokens_text = env;
  o.limits.max_memory_bytes = uint64_t(f.max_memory_gib * double(1ull << 30));
  spdlog::set_level(spdlog::level::from_str(f.log_level));
  // Every line names the replica, so merged logs of several stay readable.
  if (f.log_format == "json") {
    spdlog::set_formatter(std::make_unique<nimbus::server::JsonLogFormatter>(o.replica_id));
    nimbus::server::RouteGrpcLogsToSpdlog();
  } else {
    spdlog::set_pattern(
        absl::StrCat("%Y-%m-%dT%H:%M:%S.%e %^%l%$ nimbusd replica=", o.replica_id, " %v"));
  }
  return true;
}

// Serves until SIGINT or SIGTERM, then stops within the drain time; the
// process's exit code.
int Serve(const nimbus::server::ServerOptions& o, const std::string& port_file,
          const std::string& http_port_file) {
  // Block the stop signals before any thread exists, so every thread
  // inherits the mask and sigwait below is the one place they arrive.
  sigset_t stop_signals;
  sigemptyset(&stop_signals);
  sigaddset(&stop_signals, SIGINT);
  sigaddset(&stop_signals, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &stop_signals, nullptr);

  auto server = nimbus::server::NimbusServer::Start(o);
  if (!server.ok()) {
    spdlog::error("event=start_failed error=\"{}\"", server.status().ToString());
    return 1;
  }
  if (!(*server)->address().empty()) {
    spdlog::info("listening on {}", (*server)->address());
    // Before --port-file: whoever waits for that one finds both.
    if (!http_port_file.empty() && !WritePortFile(http_port_file, (*server)->http_port())) {
      spdlog::error("event=start_failed error=\"cannot write --http-port-file {}\"",
                    http_port_file);
      (*server)->Shutdown();
      return 1;
    }
    if (!port_file.empty() && !WritePortFile(port_file, (*server)->port())) {
      spdlog::error("event=start_failed error=\"cannot write --port-file {}\"", port_file);
      (*server)->Shutdown();
      return 1;
    }
  }
  int signal = 0;
  sigwait(&stop_signals, &signal);
  spdlog::info("event=stopping signal={}", signal);
  // The bound on stopping: whatever still runs after the drain time plus
  // a little (or a second signal), the process ends; jobs it held are
  // requeued by the next start or claimed by another replica.
  std::thread([stop_signals, deadline = std::chrono::milliseconds(o.drain_ms + 700)] {
    timespec ts{time_t(deadline.count() / 1000), long(deadline.count() % 1000) * 1'000'000};
    siginfo_t info;
    const int again = sigtimedwait(&stop_signals, &info, &ts);
    spdlog::error("event=forced_exit reason={}", again > 0 ? "second signal" : "drain timeout");
    spdlog::shutdown();
    std::_Exit(1);
  }).detach();
  (*server)->Shutdown();
  spdlog::info("event=exited");
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  nimbus::KeepFreedHeapForReuse();  // uploads and downloads stream 1 MiB chunks
  CLI::App app{"nimbusd: grows fractal volumes for Nimbus clients over gRPC"};
  DaemonFlags f;
  AddServingFlags(app, f);
  AddSecurityFlags(app, f.o, f.retention_hours, f.retention_seconds);
  AddReplicaFlags(app, f);
  app.add_option("--log-level", f.log_level, "trace, debug, info, warn, error")
      ->capture_default_str();
  app.add_option("--log-format", f.log_format,
                 "text (readable key=value lines) or json (one JSON object per line)")
      ->check(CLI::IsMember({"text", "json"}))
      ->capture_default_str();
  CLI11_PARSE(app, argc, argv);
  if (!FinishOptions(f)) return 2;
  return Serve(f.o, f.port_file, f.http_port_file);
}
