#include "core/base/module_loader.h"

#include <dlfcn.h>

#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"

namespace nimbus {

namespace {

std::vector<std::filesystem::path> Candidates(const ModuleSpec& spec) {
  if (const char* env = std::getenv(spec.env_var); env != nullptr && *env != '\0') return {env};
  std::error_code ec;
  const std::filesystem::path exe = std::filesystem::read_symlink("/proc/self/exe", ec);
  if (ec) return {spec.file_name};  // the dynamic linker's own search
  const std::filesystem::path dir = exe.parent_path();
  return {dir / spec.file_name, dir.parent_path() / "lib" / "nimbus" / spec.file_name};
}

}  // namespace

// Never unloaded: what the module makes (stores, grids) runs its code.
// Functions bind lazily, on first call, as in the program itself: binding
// every one of OpenVDB's at load cost more than the rest of a small job. A
// module built apart from its program is refused by its ABI number.
absl::StatusOr<void*> LoadModuleEntry(const ModuleSpec& spec) {
  std::vector<std::string> tried;
  for (const std::filesystem::path& path : Candidates(spec)) {
    void* handle = dlopen(path.c_str(), RTLD_LAZY | RTLD_LOCAL);
    if (handle == nullptr) {
      tried.push_back(dlerror());
      continue;
    }
    if (void* entry = dlsym(handle, spec.entry); entry != nullptr) return entry;
    return absl::FailedPreconditionError(absl::StrCat(path.string(), " has no ", spec.entry,
                                                      " (not this program's ", spec.file_name,
                                                      ")"));
  }
  return absl::FailedPreconditionError(
      absl::StrCat(spec.what, " (", spec.file_name,
                   ") is not installed beside this program; set ", spec.env_var,
                   " to its path. Tried: ", absl::StrJoin(tried, "; ")));
}

}  // namespace nimbus
