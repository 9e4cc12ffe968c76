// LoadVdbModule: finds and loads libnimbus_vdb.so on first use (see
// vdb_module.h for why OpenVDB is a module).
#include "core/io/vdb_module.h"

#include <dlfcn.h>

#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"

namespace nimbus {

namespace {

std::vector<std::filesystem::path> ModuleCandidates() {
  if (const char* env = std::getenv("NIMBUS_VDB_MODULE"); env != nullptr && *env != '\0')
    return {env};
  std::error_code ec;
  const std::filesystem::path exe = std::filesystem::read_symlink("/proc/self/exe", ec);
  if (ec) return {kVdbModuleName};  // the dynamic linker's own search
  const std::filesystem::path dir = exe.parent_path();
  return {dir / kVdbModuleName, dir.parent_path() / "lib" / "nimbus" / kVdbModuleName};
}

absl::Status NotAModule(const std::filesystem::path& path, const std::string& why) {
  return absl::FailedPreconditionError(
      absl::StrCat(path.string(), ": ", why, " (not this program's ", kVdbModuleName, ")"));
}

// Loaded once and never unloaded: results and grids it made may outlive
// any one call.
absl::StatusOr<const VdbModule*> Load() {
  std::vector<std::string> tried;
  for (const std::filesystem::path& path : ModuleCandidates()) {
    void* handle = dlopen(path.c_str(), RTLD_NOW | RTLD_LOCAL);
    if (handle == nullptr) {
      tried.push_back(dlerror());
      continue;
    }
    void* entry = dlsym(handle, kVdbModuleEntry);
    if (entry == nullptr) return NotAModule(path, absl::StrCat("no ", kVdbModuleEntry));
    const VdbModule* table = reinterpret_cast<VdbModuleEntry*>(entry)();
    if (table == nullptr || table->abi != kVdbModuleAbi)
      return NotAModule(path, absl::StrCat("table version ", table ? table->abi : 0,
                                           ", expected ", kVdbModuleAbi));
    return table;
  }
  return absl::FailedPreconditionError(absl::StrCat(
      "OpenVDB support (", kVdbModuleName,
      ") is not installed beside this program; set NIMBUS_VDB_MODULE to its path. Tried: ",
      absl::StrJoin(tried, "; ")));
}

}  // namespace

absl::StatusOr<const VdbModule*> LoadVdbModule() {
  // A function-local static: initialised once, other threads wait for it.
  static const absl::StatusOr<const VdbModule*> module = Load();
  return module;
}

}  // namespace nimbus
