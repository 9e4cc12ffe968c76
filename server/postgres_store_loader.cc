// OpenPostgresJobStore: finds and loads libnimbus_postgres.so on first use
// (see postgres_module.h for why the store is a module).
#include <memory>
#include <string>

#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "core/base/module_loader.h"
#include "server/job_store.h"
#include "server/job_store_util.h"
#include "server/postgres_module.h"

namespace nimbus::server {

bool IsPostgresUrl(const std::string& url) {
  return absl::StartsWith(url, "postgresql://") || absl::StartsWith(url, "postgres://");
}

absl::StatusOr<std::unique_ptr<JobStore>> OpenPostgresJobStore(const std::string& url) {
  if (!IsPostgresUrl(url))
    return absl::InvalidArgumentError(
        absl::StrCat("--store ", RedactUrl(url), ": expected postgresql://… or postgres://…"));
  // Loaded once; a failure is remembered, as a missing file stays missing.
  static const absl::StatusOr<void*> module = LoadModuleEntry(
      {"PostgreSQL support", kPostgresModuleName, kPostgresModuleEntry, "NIMBUS_POSTGRES_MODULE"});
  if (!module.ok())
    return absl::Status(module.status().code(),
                        absl::StrCat("--store ", RedactUrl(url), ": ", module.status().message()));
  absl::StatusOr<std::unique_ptr<JobStore>> out = absl::UnknownError("not opened");
  reinterpret_cast<OpenPostgresEntry*>(*module)(url, out);
  return out;
}

}  // namespace nimbus::server
