// The job store kinds the JobStore contract tests run against: a fresh,
// empty store of each kind, and a way to open it again (a second replica,
// or a restart). PostgreSQL stores live in a database of their own on the
// test process's private server (tests/support/postgres_server.h).
// TimedSqlite is SQLite behind the TimedJobStore nimbusd puts in front of
// every store, so the contract is checked through it too.
// Header-only: the server library comes from the test executable.
#pragma once

#include <atomic>
#include <filesystem>
#include <memory>
#include <ostream>
#include <string>

#include "absl/status/statusor.h"
#include "server/job_store.h"
#include "server/timed_job_store.h"
#include "tests/support/postgres_server.h"

namespace nimbus::testing {

enum class StoreKind { kSqlite, kPostgres, kTimedSqlite };

inline std::string StoreKindName(StoreKind kind) {
  return kind == StoreKind::kSqlite        ? "Sqlite"
         : kind == StoreKind::kTimedSqlite ? "TimedSqlite"
                                           : "Postgres";
}

/// @brief Counts the calls TimedSqlite stores report.
struct StoreCallCounter : server::StoreCallObserver {
  std::atomic<int64_t> calls{0};
  void ObserveStoreCall(server::StoreCall, double) override { calls.fetch_add(1); }
  static StoreCallCounter& Shared() {
    static StoreCallCounter counter;
    return counter;
  }
};

/// For GoogleTest's names of parameterized tests (and so ctest's).
inline void PrintTo(StoreKind kind, std::ostream* os) { *os << StoreKindName(kind); }

/// The URL of a fresh, empty database on the test process's private
/// PostgreSQL server. UNAVAILABLE (the reason in the message) when
/// PostgreSQL is not installed: tests skip then.
inline absl::StatusOr<std::string> FreshPostgresUrl() {
  std::string why;
  PostgresServer* server = PostgresServer::Shared(&why);
  if (server == nullptr) return absl::UnavailableError(why);
  return server->NewDatabase();
}

/// @brief Where one test's store lives: a SQLite file or a PostgreSQL URL.
struct StoreLocation {
  StoreKind kind = StoreKind::kSqlite;
  /// The SQLite file, or the postgresql:// URL.
  std::string where;

  /// A fresh location; SQLite files go in `dir`. UNAVAILABLE (the reason
  /// in the message) when PostgreSQL is not installed.
  static absl::StatusOr<StoreLocation> Fresh(StoreKind kind, const std::filesystem::path& dir) {
    if (kind != StoreKind::kPostgres) return StoreLocation{kind, (dir / "jobs.db").string()};
    absl::StatusOr<std::string> url = FreshPostgresUrl();
    if (!url.ok()) return url.status();
    return StoreLocation{kind, *url};
  }

  /// Opens (another handle on) the store.
  absl::StatusOr<std::unique_ptr<server::JobStore>> Open() const {
    if (kind == StoreKind::kPostgres) return server::OpenPostgresJobStore(where);
    auto store = server::OpenSqliteJobStore(where);
    if (!store.ok() || kind == StoreKind::kSqlite) return store;
    auto timed = std::make_unique<server::TimedJobStore>(std::move(*store));
    timed->set_observer(&StoreCallCounter::Shared());
    return std::unique_ptr<server::JobStore>(std::move(timed));
  }
};

}  // namespace nimbus::testing
