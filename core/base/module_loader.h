// LoadModuleEntry: finds one of Nimbus's optional shared modules
// (libnimbus_vdb.so, libnimbus_postgres.so) and returns its entry point.
//
//   absl::StatusOr<void*> entry = LoadModuleEntry(
//       {"OpenVDB support", "libnimbus_vdb.so", "NimbusVdbModule", "NIMBUS_VDB_MODULE"});
//
// Programs load these with dlopen so that their start-up does not pay for
// libraries most runs never touch (docs/operator_guide.md).
#pragma once

#include "absl/status/statusor.h"

namespace nimbus {

struct ModuleSpec {
  const char* what;       // for messages: "OpenVDB support"
  const char* file_name;  // libnimbus_vdb.so
  const char* entry;      // the extern "C" symbol to return
  const char* env_var;    // a path that overrides the search
};

/// @brief Looks at $env_var if set, else beside the executable, then in
/// ../lib/nimbus/ relative to it. Returns the first candidate that loads
/// (RTLD_LAZY | RTLD_LOCAL, never unloaded) and its entry symbol;
/// FAILED_PRECONDITION naming every path tried when none loads, or naming
/// the file when it lacks the entry.
absl::StatusOr<void*> LoadModuleEntry(const ModuleSpec& spec);

}  // namespace nimbus
