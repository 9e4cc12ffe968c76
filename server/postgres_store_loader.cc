// OpenPostgresJobStore: finds and loads libnimbus_postgres.so on first use
// (see postgres_module.h for why the store is a module).
#include <dlfcn.h>

#include <cstdlib>
#include <filesystem>
#include <mutex>
#include <string>
#include <vector>

#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "server/job_store.h"
#include "server/job_store_util.h"
#include "server/postgres_module.h"

namespace nimbus::server {

namespace {

std::vector<std::filesystem::path> ModuleCandidates() {
  if (const char* env = std::getenv("NIMBUS_POSTGRES_MODULE"); env != nullptr && *env != '\0')
    return {env};
  std::error_code ec;
  const std::filesystem::path exe = std::filesystem::read_symlink("/proc/self/exe", ec);
  if (ec) return {kPostgresModuleName};  // the dynamic linker's own search
  const std::filesystem::path dir = exe.parent_path();
  return {dir / kPostgresModuleName, dir.parent_path() / "lib" / "nimbus" / kPostgresModuleName};
}

struct Loaded {
  OpenPostgresEntry* entry = nullptr;
  absl::Status status;
};

// Loaded once and never unloaded: the stores it opens run its code.
Loaded LoadModule() {
  std::vector<std::string> tried;
  for (const std::filesystem::path& path : ModuleCandidates()) {
    void* handle = dlopen(path.c_str(), RTLD_NOW | RTLD_LOCAL);
    if (handle == nullptr) {
      tried.push_back(dlerror());
      continue;
    }
    void* entry = dlsym(handle, kPostgresModuleEntry);
    if (entry != nullptr) return {reinterpret_cast<OpenPostgresEntry*>(entry), absl::OkStatus()};
    return {nullptr, absl::FailedPreconditionError(absl::StrCat(
                         path.string(), " has no ", kPostgresModuleEntry, " (not a Nimbus module)"))};
  }
  return {nullptr, absl::FailedPreconditionError(absl::StrCat(
                       "PostgreSQL support (", kPostgresModuleName,
                       ") is not installed beside this program; set NIMBUS_POSTGRES_MODULE to "
                       "its path. Tried: ",
                       absl::StrJoin(tried, "; ")))};
}

}  // namespace

bool IsPostgresUrl(const std::string& url) {
  return absl::StartsWith(url, "postgresql://") || absl::StartsWith(url, "postgres://");
}

absl::StatusOr<std::unique_ptr<JobStore>> OpenPostgresJobStore(const std::string& url) {
  if (!IsPostgresUrl(url))
    return absl::InvalidArgumentError(
        absl::StrCat("--store ", RedactUrl(url), ": expected postgresql://… or postgres://…"));
  static const Loaded module = LoadModule();
  if (!module.status.ok())
    return absl::Status(module.status.code(),
                        absl::StrCat("--store ", RedactUrl(url), ": ", module.status.message()));
  absl::StatusOr<std::unique_ptr<JobStore>> out = absl::UnknownError("not opened");
  module.entry(url, out);
  return out;
}

}  // namespace nimbus::server
