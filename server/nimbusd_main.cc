// nimbusd: the Nimbus job server.
#include <CLI/CLI.hpp>
#include <spdlog/spdlog.h>

#include <csignal>
#include <thread>

#include "server/server.h"

namespace {
std::atomic<bool> g_stop{false};
void OnSignal(int) { g_stop = true; }
}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"nimbusd: grows fractal volumes for Nimbus clients over gRPC"};
  nimbus::server::ServerOptions o;
  std::string data_dir = o.data_dir.string();
  double max_memory_gib = double(o.limits.max_memory_bytes) / double(1ull << 30);
  std::string log_level = "info";
  app.add_option("--listen", o.listen, "host:port to serve on")->capture_default_str();
  app.add_option("--data-dir", data_dir, "folder for the job database and results")
      ->capture_default_str();
  app.add_option("--workers", o.workers, "jobs run at once")->capture_default_str()->check(
      CLI::Range(1, 256));
  app.add_option("--threads-per-job", o.threads_per_job,
                 "engine threads per job (0: cores / workers)")
      ->capture_default_str();
  app.add_option("--max-resolution", o.limits.max_resolution, "largest grid axis, voxels")
      ->capture_default_str();
  app.add_option("--max-voxels", o.limits.max_voxels, "largest grid, voxels")->capture_default_str();
  app.add_option("--max-memory-gib", max_memory_gib, "largest estimated job memory, GiB")
      ->capture_default_str();
  app.add_option("--max-iterations", o.limits.max_iterations, "largest iteration budget")
      ->capture_default_str();
  app.add_option("--log-level", log_level, "trace, debug, info, warn, error")->capture_default_str();
  CLI11_PARSE(app, argc, argv);
  o.data_dir = data_dir;
  o.limits.max_memory_bytes = uint64_t(max_memory_gib * double(1ull << 30));
  spdlog::set_level(spdlog::level::from_str(log_level));
  spdlog::set_pattern("%Y-%m-%dT%H:%M:%S.%e %^%l%$ nimbusd %v");

  auto server = nimbus::server::NimbusServer::Start(o);
  if (!server.ok()) {
    spdlog::error("event=start_failed error=\"{}\"", server.status().ToString());
    return 1;
  }
  std::signal(SIGINT, OnSignal);
  std::signal(SIGTERM, OnSignal);
  while (!g_stop) std::this_thread::sleep_for(std::chrono::milliseconds(100));
  (*server)->Shutdown();
  return 0;
}
