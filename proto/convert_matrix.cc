// Converts chaos_game.matrices. Placeholder until IFS matrices land.
#include "proto/convert_internal.h"

namespace nimbus::spec::internal {

absl::Status ConvertMatrixChaosGame(const v1::ChaosGame&, const Limits&, int, ConvertedJob&) {
  return absl::UnimplementedError("chaos_game.matrices: not available in this build yet");
}

}  // namespace nimbus::spec::internal
