// The one place where a nimbus.v1.JobSpec is validated and converted into
// a protobuf-free JobPlan (core/plan/job_plan.h). Every error names the offending field by its path, e.g.
// "chaos_game.ifs.maps[2].steps[0].rotate.axis: must not be zero".
#pragma once

#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "core/plan/job_plan.h"
#include "nimbus/v1/spec.pb.h"

namespace nimbus::spec {

/// Server-side limits, checked before anything is allocated.
struct Limits {
  int32_t max_resolution = 4096;             // per axis
  int64_t max_voxels = int64_t{2048} * 2048 * 2048;
  /// Checked by the server's memory admission, not by ConvertSpec.
  uint64_t max_memory_bytes = uint64_t{16} << 30;
  uint64_t max_iterations = uint64_t{1} << 40;
  int32_t max_maps = 4096;
  /// Uploaded assets (meshes, grids) by sha256; see docs/assets.md.
  std::filesystem::path asset_dir;
  /// Accept assets given by local path. Only in-process servers do: a
  /// network server must not read its host's files on a client's word.
  bool allow_local_paths = true;
};

/// Validates `spec` against `limits` and converts it into a JobPlan.
/// INVALID_ARGUMENT for malformed specs, RESOURCE_EXHAUSTED beyond the
/// structural limits (resolution, voxels, maps, iterations). Pure: the same
/// spec and asset files give the same plan; memory admission (pilot census,
/// memory limit) is the server's next step (server/memory_admission.h).
absl::StatusOr<JobPlan> ConvertSpec(const v1::JobSpec& spec, const Limits& limits);

/// Composes Step messages right to left into one affine map. `path` prefixes
/// error messages.
absl::StatusOr<Affine3> ComposeSteps(const google::protobuf::RepeatedPtrField<v1::Step>& steps,
                                     const std::string& path);

/// A jelly push (a spec impulse, or a poke on a running job) for a jelly
/// of `bodies` bodies. Errors are INVALID_ARGUMENT naming fields under
/// `path` (e.g. "push.body: no body 7 ...").
absl::StatusOr<JellyPoke> ConvertJellyPush(const v1::JellyPush& push, int bodies,
                                           const std::string& path);

/// Lower-case hex SHA-256 of the spec's deterministic binary serialisation,
/// without the fields that do not change the result (`shards`, `no_cache`):
/// the canonical hash named in result metadata and used by the result cache.
std::string SpecHash(const v1::JobSpec& spec);

/// Most shards of one job (docs/sharding.md).
inline constexpr uint32_t kMaxShards = 256;

}  // namespace nimbus::spec
