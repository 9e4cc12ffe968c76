// The one place where a nimbus.v1.JobSpec is validated and converted into
// core objects. Every error names the offending field by its path, e.g.
// "chaos_game.ifs.maps[2].steps[0].rotate.axis: must not be zero".
#pragma once

#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "core/chaos/chaos_game.h"
#include "core/base/geometry.h"
#include "core/io/vdb_io.h"
#include "nimbus/v1/spec.pb.h"

namespace nimbus::spec {

/// Server-side limits, checked before anything is allocated.
struct Limits {
  int32_t max_resolution = 4096;             // per axis
  int64_t max_voxels = int64_t{2048} * 2048 * 2048;
  uint64_t max_memory_bytes = uint64_t{16} << 30;
  uint64_t max_iterations = uint64_t{1} << 40;
  int32_t max_maps = 4096;
  /// Uploaded assets (meshes, grids) by sha256; see docs/assets.md.
  std::filesystem::path asset_dir;
  /// Accept assets given by local path. Only in-process servers do: a
  /// network server must not read its host's files on a client's word.
  bool allow_local_paths = true;
};

/// Which generator a job runs; selects the runner in the server.
enum class Generator { kChaosGame, kSetIfs, kIfsMatrix };

/// The set-IFS plan; defined in proto/convert_set_ifs.h.
struct SetIfsPlan;
/// The IFS-matrix plan; defined in proto/convert_matrix.h.
struct IfsMatrixPlan;

/// @brief A validated job, ready for the engine.
struct ConvertedJob {
  std::string name;
  Generator generator = Generator::kChaosGame;
  GridFrame frame;
  /// Set for Generator::kChaosGame.
  ChaosGameParams chaos_game;
  /// Set for Generator::kSetIfs.
  std::shared_ptr<const SetIfsPlan> set_ifs;
  /// Set for Generator::kIfsMatrix (chaos_game.matrices).
  std::shared_ptr<const IfsMatrixPlan> ifs_matrix;
  DensityOptions density;
  std::vector<std::string> warnings;
  /// Largest singular value of each map's affine part.
  std::vector<double> contraction_factors;
  uint64_t estimated_memory_bytes = 0;
  /// Units of progress the job reports in total.
  uint64_t total_work = 0;
};

/// Validates `spec` against `limits` for a run on `threads` threads.
/// INVALID_ARGUMENT for malformed specs, RESOURCE_EXHAUSTED beyond limits.
absl::StatusOr<ConvertedJob> ConvertSpec(const v1::JobSpec& spec, const Limits& limits,
                                         int threads);

/// Composes Step messages right to left into one affine map. `path` prefixes
/// error messages.
absl::StatusOr<Affine3> ComposeSteps(const google::protobuf::RepeatedPtrField<v1::Step>& steps,
                                     const std::string& path);

/// Lower-case hex SHA-256 of the spec's deterministic binary serialisation.
std::string SpecHash(const v1::JobSpec& spec);

}  // namespace nimbus::spec
