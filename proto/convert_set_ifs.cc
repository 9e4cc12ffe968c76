// Converts the set_ifs generator. Placeholder until condensation sets land.
#include "proto/convert_internal.h"

namespace nimbus::spec::internal {

absl::Status ConvertSetIfs(const v1::SetIfs&, const Limits&, int, ConvertedJob&) {
  return absl::UnimplementedError("set_ifs: not available in this build yet");
}

}  // namespace nimbus::spec::internal
