// LoadVdbModule: finds and loads libnimbus_vdb.so on first use (see
// vdb_module.h for why OpenVDB is a module).
#include "core/io/vdb_module.h"

#include "core/base/module_loader.h"

namespace nimbus {

namespace {

absl::StatusOr<const VdbModule*> Load() {
  return LoadVdbModuleTable<VdbModule>(kVdbModuleEntry, kVdbModuleAbi);
}

}  // namespace

absl::StatusOr<void*> LoadVdbModuleSymbol(const char* symbol) {
  return LoadModuleEntry({"OpenVDB support", kVdbModuleName, symbol, "NIMBUS_VDB_MODULE"});
}

absl::StatusOr<const VdbModule*> LoadVdbModule() {
  // A function-local static: initialised once, other threads wait for it.
  static const absl::StatusOr<const VdbModule*> module = Load();
  return module;
}

}  // namespace nimbus
