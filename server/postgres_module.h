// The PostgreSQL job store lives in its own module, libnimbus_postgres.so,
// which the server loads only when it is given a postgresql:// store: a
// server on SQLite (and every `nimbus` run with its embedded server) then
// never maps libpq, libpqxx and their Kerberos, LDAP and TLS libraries,
// which cost each process start some 10-25 ms and ~7 MB of memory.
#pragma once

#include <memory>
#include <string>

#include "absl/status/statusor.h"
#include "server/job_store.h"

#define NIMBUS_POSTGRES_EXPORT __attribute__((visibility("default")))

namespace nimbus::server {

/// File name of the module, looked for in $NIMBUS_POSTGRES_MODULE (a full
/// path), then beside the running program, then in ../lib/nimbus/ from it.
inline constexpr char kPostgresModuleName[] = "libnimbus_postgres.so";
/// The one symbol the module exports.
inline constexpr char kPostgresModuleEntry[] = "NimbusOpenPostgresJobStore";

/// The entry's type: PostgresJobStore::Open, with its result in `out`. C
/// linkage only so that dlsym finds it by that name; both sides are built
/// together, so C++ types may cross.
using OpenPostgresEntry = void(const std::string& url,
                               absl::StatusOr<std::unique_ptr<JobStore>>& out);

}  // namespace nimbus::server
