// LoadVdbModule: finds and loads libnimbus_vdb.so on first use (see
// vdb_module.h for why OpenVDB is a module).
#include "core/io/vdb_module.h"

#include "absl/strings/str_cat.h"
#include "core/base/file_digests.h"
#include "core/base/module_loader.h"
#include "core/base/status_macros.h"

namespace nimbus {

namespace {

absl::StatusOr<const VdbModule*> Load() {
  NIMBUS_ASSIGN_OR_RETURN(void* entry,
                          LoadModuleEntry({"OpenVDB support", kVdbModuleName, kVdbModuleEntry,
                                           "NIMBUS_VDB_MODULE"}));
  const VdbModule* table = reinterpret_cast<VdbModuleEntry*>(entry)();
  if (table == nullptr || table->abi != kVdbModuleAbi)
    return absl::FailedPreconditionError(absl::StrCat(kVdbModuleName, ": table version ",
                                                      table ? table->abi : 0, ", expected ",
                                                      kVdbModuleAbi));
  // The module's digests go to this program's memo, which the result store
  // recalls instead of reading the file again.
  table->set_digest_sink(&RememberFileSha256);
  return table;
}

}  // namespace

absl::StatusOr<const VdbModule*> LoadVdbModule() {
  // A function-local static: initialised once, other threads wait for it.
  static const absl::StatusOr<const VdbModule*> module = Load();
  return module;
}

}  // namespace nimbus
