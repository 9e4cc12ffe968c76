// A throwaway PostgreSQL server for tests: Debian's initdb and pg_ctl into a
// temporary folder, listening only on a unix socket in that folder, stopped
// and removed afterwards. Runs as the `postgres` user when the test runs as
// root (PostgreSQL refuses to run as root).
#pragma once

#include <sys/types.h>

#include <filesystem>
#include <memory>
#include <string>

#include "absl/status/statusor.h"

namespace nimbus::testing {

/// @brief One private PostgreSQL server; each test takes a fresh database.
class PostgresServer {
 public:
  /// Starts a server, or UNAVAILABLE when the PostgreSQL binaries are not
  /// installed (the message says what to install; tests skip on it).
  static absl::StatusOr<std::unique_ptr<PostgresServer>> Start();
  /// The server of this process, started on first use and stopped at exit;
  /// null with `*why` set when it cannot start. Under ctest it is the run's
  /// server instead (kFixtureDirEnv), shared by every test process.
  static PostgresServer* Shared(std::string* why);

  /// One server for a whole ctest run (tests/postgres_fixture.cc): each
  /// test process would otherwise start its own, about a second apiece.
  /// StartDetached leaves a server running in `dir` (replacing whatever a
  /// killed run left there); StopDetached stops it and removes `dir`.
  static constexpr const char* kFixtureDirEnv = "NIMBUS_TEST_POSTGRES_DIR";
  static absl::Status StartDetached(const std::filesystem::path& dir);
  static void StopDetached(const std::filesystem::path& dir);
  /// Stops the server and removes its folder (a watchdog process does the
  /// same if this process dies first).
  ~PostgresServer();
  PostgresServer(const PostgresServer&) = delete;
  PostgresServer& operator=(const PostgresServer&) = delete;

  /// Creates an empty database and returns its postgresql:// URL.
  absl::StatusOr<std::string> NewDatabase();
  /// The URL of the `postgres` maintenance database.
  std::string Url(const std::string& database = "postgres") const;
  const std::filesystem::path& dir() const { return dir_; }

 private:
  explicit PostgresServer(std::filesystem::path dir, std::filesystem::path bin)
      : dir_(std::move(dir)), bin_(std::move(bin)) {}
  absl::Status Init(bool watchdog);
  // A running fixture server in `dir`, or null.
  static std::unique_ptr<PostgresServer> Attach(const std::filesystem::path& dir);

  std::filesystem::path dir_;
  std::filesystem::path bin_;
  // Starts the watchdog that stops the server and removes its folder when
  // this process ends, however it ends (a crashed test leaves nothing).
  void StartWatchdog();

  bool running_ = false;
  bool attached_ = false;  // the run's server: neither stopped nor removed here
  int next_db_ = 0;
  // The write end of the watchdog's pipe, and its pid.
  int watchdog_fd_ = -1;
  pid_t watchdog_ = -1;
};

/// The folder holding initdb and pg_ctl (/usr/lib/postgresql/N/bin, newest
/// N), or empty when there is none.
std::filesystem::path PostgresBinDir();

}  // namespace nimbus::testing
