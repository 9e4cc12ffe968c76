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

/// The largest magnitude of any coordinate, bound, matrix entry, weight or
/// probability of a spec: far beyond any useful fractal, far below where
/// the engines' arithmetic overflows, so an absurd number is refused at
/// submit by name instead of failing the run.
inline constexpr double kMaxMagnitude = 1e12;
/// Finite and within ±kMaxMagnitude.
bool InRange(double x);
/// INVALID_ARGUMENT "path: must be finite and within ±1e12, got x" unless
/// InRange(x).
absl::Status CheckNumber(double x, const std::string& path);
/// Every component InRange (the name says finite; it also bounds them).
bool Finite(const v1::Vec3& v);
/// INVALID_ARGUMENT naming `path` for a ProbabilityMode this server does
/// not know (a newer client's, or a bad number).
absl::Status CheckProbabilityMode(v1::ProbabilityMode mode, const std::string& path);
/// Bounds of output.max_voxels and output.target_file_bytes when set.
inline constexpr int64_t kMinOutputVoxels = 512;
inline constexpr int64_t kMaxOutputVoxels = int64_t{1} << 40;
inline constexpr int64_t kMinTargetFileBytes = int64_t{1} << 16;
inline constexpr int64_t kMaxTargetFileBytes = int64_t{1} << 50;
/// Most warm-up steps per walker (chaos_game.warmup).
inline constexpr uint32_t kMaxWarmup = 1'000'000;
Vec3 ToVec3(const v1::Vec3& v);
/// A Map message as a core PointMap (pre steps, variations, post, colour).
absl::StatusOr<PointMap> ConvertMap(const v1::Map& m, const std::string& path);

/// The engine options shared by plain and matrix chaos games: colour, raw
/// counts, convergence and splatting.
absl::Status ConvertEngineOptions(const v1::ChaosGame& cg, ChaosGameParams& params,
                                  DensityOptions& density);
/// chaos_game.iterations and warmup: iterations > 0, warmup <= kMaxWarmup,
/// and iterations plus warm-up steps (warmup × ChaosGame::kWalkers × chunks
/// of ChaosGame::kChunkIterations) within limits.max_iterations.
absl::Status CheckIterations(const v1::ChaosGame& cg, const Limits& limits);

/// Per-kind converters: fill `plan` (kind, work, warnings) from their part
/// of the spec. The grid (plan.frame) and output are already converted.
absl::Status ConvertChaosGame(const v1::ChaosGame& cg, const Limits& limits, JobPlan& plan);
/// chaos_game.matrices: called by ConvertChaosGame when matrices are set.
absl::Status ConvertMatrixChaosGame(const v1::ChaosGame& cg, const Limits& limits,
                                    JobPlan& plan);
absl::Status ConvertSetIfs(const v1::SetIfs& s, const Limits& limits, JobPlan& plan);
/// A set source (mesh, grid, shape, union) at `field`, files resolved and
/// meshes parsed: set IFS condensation sets and shaped fractal fields.
absl::Status ConvertSetSource(const v1::SetSource& s, const std::string& field,
                              const Limits& limits, JobPlan& job, SetSourcePlan& out);
absl::Status ConvertFractalField(const v1::FractalField& f, const Limits& limits, JobPlan& plan);
/// JobSpec.detail: a static 3D field that multiplies the density.
absl::Status ConvertFieldDetail(const v1::FieldDetail& d, JobPlan& plan);
absl::Status ConvertJelly(const v1::Jelly& j, const Limits& limits, JobPlan& plan);
/// JobSpec.image, after the kind's converter: a chaos game's picture.
absl::Status ConvertImage(const v1::JobSpec& spec, JobPlan& plan);
/// A picture's look (image.look, explore.look) at `path`; the glow radius
/// stays 0 when left to its default, which `default_glow_radius` reports.
absl::Status ConvertLook(const v1::Look& l, const std::string& path, LookParams& look,
                         bool* default_glow_radius);
/// The explore generator (convert_explore.cc).
absl::Status ConvertExplore(const v1::Explore& e, const Limits& limits, JobPlan& plan);
/// grid.auto_frame, after the kind's converter.
absl::Status ConvertAutoFrame(const v1::JobSpec& spec, JobPlan& plan);

}  // namespace nimbus::spec::internal
