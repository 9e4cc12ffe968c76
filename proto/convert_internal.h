// Shared helpers of the spec converters (proto/convert_*.cc). Not a public
// header: only the converters include it.
#pragma once

#include <string>

#include "absl/status/statusor.h"
#include "absl/strings/str_cat.h"
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
absl::Status ConvertEngineOptions(const v1::ChaosGame& cg, ConvertedJob& job);

/// Memory a chaos-game run of `params` needs on `threads` threads. When the
/// geometric bound is above 1 GiB (or the limit), a short pilot run measures
/// the tiles the attractor really touches (ChaosGame::Pilot) and the
/// estimate uses those. Also sets params.memory_budget to the limit, the
/// run-time safety net. `pilot_samples` is set to the pilot's size, or 0.
ChaosGameMemory EstimateChaosGameMemory(ChaosGameParams& params, int threads,
                                        const DensityOptions& density, const Limits& limits,
                                        uint64_t* pilot_samples);

/// Per-generator converters: fill `job` (generator, plan, total_work,
/// estimated_memory_bytes, warnings) from their part of the spec. The grid
/// (job.frame) is already converted.
absl::Status ConvertChaosGame(const v1::ChaosGame& cg, const Limits& limits, int threads,
                              ConvertedJob& job);
/// chaos_game.matrices: called by ConvertChaosGame when matrices are set.
absl::Status ConvertMatrixChaosGame(const v1::ChaosGame& cg, const Limits& limits, int threads,
                                    ConvertedJob& job);
absl::Status ConvertSetIfs(const v1::SetIfs& s, const Limits& limits, int threads,
                           ConvertedJob& job);

}  // namespace nimbus::spec::internal
