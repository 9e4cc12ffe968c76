// Shared helpers of the spec converters (proto/convert_*.cc). Not a public
// header: only the converters include it.
#pragma once

#include <string>

#include "absl/status/statusor.h"
#include "absl/strings/str_cat.h"
#include "core/base/status_macros.h"
#include "proto/spec_convert.h"

namespace nimbus::spec::internal {

using absl::StrCat;

/// INVALID_ARGUMENT "path: what".
absl::Status Invalid(const std::string& path, const std::string& what);
bool Finite(const v1::Vec3& v);
Vec3 ToVec3(const v1::Vec3& v);
/// "1.50 GiB".
std::string GiB(uint64_t bytes);
/// A Map message as a core PointMap (pre steps, variations, post, colour).
absl::StatusOr<PointMap> ConvertMap(const v1::Map& m, const std::string& path);

/// The engine options shared by plain and matrix chaos games: colour, raw
/// counts, convergence and splatting.
absl::Status ConvertEngineOptions(const v1::ChaosGame& cg, ChaosGameParams& params,
                                  DensityOptions& density);
/// chaos_game.iterations, within the server limit.
absl::Status CheckIterations(const v1::ChaosGame& cg, const Limits& limits);

/// Per-kind converters: fill `plan` (kind, work, warnings) from their part
/// of the spec. The grid (plan.frame) and output are already converted.
absl::Status ConvertChaosGame(const v1::ChaosGame& cg, const Limits& limits, JobPlan& plan);
/// chaos_game.matrices: called by ConvertChaosGame when matrices are set.
absl::Status ConvertMatrixChaosGame(const v1::ChaosGame& cg, const Limits& limits,
                                    JobPlan& plan);
absl::Status ConvertSetIfs(const v1::SetIfs& s, const Limits& limits, JobPlan& plan);

}  // namespace nimbus::spec::internal
