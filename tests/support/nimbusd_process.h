// A nimbusd child process for end-to-end tests. nimbusd binds a port of its
// own choosing and reports it through --port-file, so no test ever guesses
// a free port that someone else may take first.
#pragma once

#include <sys/types.h>

#include <filesystem>
#include <string>
#include <vector>

#include "absl/status/status.h"

namespace nimbus::testing {

/// @brief Starts, kills and stops one nimbusd at a time on one data folder.
class NimbusdProcess {
 public:
  /// `data_dir` holds the job database and results (created if needed);
  /// `args` go on nimbusd's command line after the harness's own
  /// (--listen, --port-file, --data-dir), e.g. {"--lease-ms", "600000"}.
  explicit NimbusdProcess(std::filesystem::path data_dir, std::vector<std::string> args = {});
  /// Kills a running nimbusd (kill -9).
  ~NimbusdProcess();
  NimbusdProcess(const NimbusdProcess&) = delete;
  NimbusdProcess& operator=(const NimbusdProcess&) = delete;

  /// Starts nimbusd and returns once it listens. `port` 0 lets it pick any
  /// free port; a restart may pass the previous port() so that clients
  /// holding the old address reconnect to the new process.
  absl::Status Start(int port = 0);
  /// kill -9, as a crash would, and reaps the process.
  void Kill();
  /// SIGTERM and waits for a graceful exit; the exit code, or -1 when the
  /// process died of a signal or was not running.
  int Stop();

  bool running() const { return pid_ > 0; }
  /// The running process's id, or -1.
  pid_t pid() const { return pid_; }
  /// The port of the last successful Start.
  int port() const { return port_; }
  /// "127.0.0.1:PORT".
  std::string target() const;
  /// Replaces the extra arguments for the next Start.
  void set_args(std::vector<std::string> args) { args_ = std::move(args); }
  /// The host of --listen for the next Start (default "127.0.0.1"), e.g.
  /// "0.0.0.0" to try the non-loopback rule; target() stays on 127.0.0.1.
  void set_listen_host(std::string host) { listen_host_ = std::move(host); }
  /// Sends nimbusd's stdout and stderr to `path` from the next Start on
  /// (default: the test's own), so a test can read what it logged.
  void set_log_file(std::filesystem::path path) { log_file_ = std::move(path); }

 private:
  absl::Status AwaitPortFile(const std::filesystem::path& port_file);

  std::filesystem::path data_dir_;
  std::vector<std::string> args_;
  std::string listen_host_ = "127.0.0.1";
  std::filesystem::path log_file_;
  pid_t pid_ = -1;
  int port_ = 0;
};

}  // namespace nimbus::testing
