// @brief A validated job, ready for its engine: the part every job kind
// shares (name, grid, density output, warnings, the work it will report)
// and the kind's own plan. Protobuf-free: spec::ConvertSpec makes it from a
// nimbus.v1.JobSpec, the server's admission prices it, a runner runs it.
//
// Adding a job kind (docs/architecture.md):
//   1. its plan type, beside its engine in core/<family>/, added to JobKindPlan;
//   2. a proto message in proto/nimbus/v1/ and a converter in proto/convert_*.cc,
//      called from ConvertSpec's switch in proto/spec_convert.cc;
//   3. a runner in server/, one RunKind overload in server/job_runner.h;
//   4. its memory price in server/memory_admission.cc.
// std::visit over JobKindPlan makes steps 3 and 4 compile errors until done.
#pragma once

#include <cstdint>
#include <string>
#include <string_view>
#include <variant>
#include <vector>

#include "core/base/geometry.h"
#include "core/chaos/auto_frame.h"
#include "core/chaos/chaos_game.h"
#include "core/chaos/ifs_explorer.h"
#include "core/chaos/image_plane.h"
#include "core/grid/image_look.h"
#include "core/io/image_io.h"
#include "core/field/field_plan.h"
#include "core/io/vdb_io.h"
#include "core/jelly/jelly_plan.h"
#include "core/matrix/ifs_matrix_plan.h"
#include "core/sets/set_ifs_plan.h"

namespace nimbus {

/// @brief A picture of a chaos game (docs/images.md).
struct ImageJob {
  int width = 0, height = 0;  // output pixels; height 0: DefaultImageHeight
  int supersample = 1;
  ImageView view;
  ImageFormat format = ImageFormat::kPng8;
  LookParams look;
  bool image_only = false;
  int preview_size = 256;
  /// The glow radius was left to its default (1 % of the larger side).
  bool default_glow_radius = true;
};

/// @brief A plain (or nonlinear) IFS run by the chaos game.
struct ChaosGamePlan {
  ChaosGameParams params;
  std::optional<ImageJob> image;
  /// Fit params.frame.bounds to the attractor before running.
  std::optional<AutoFrameParams> auto_frame;
};

/// @brief The random IFS explorer (docs/explore.md): thumbnails on a
/// contact sheet and one spec per kept candidate.
struct ExplorePlan {
  ExploreParams params;
  /// Cells per row of the contact sheet (0: square-ish).
  int columns = 0;
  /// The serialised nimbus.v1.JobSpec every candidate's spec starts from,
  /// made by the spec converter; the runner adds the maps, seed and framing.
  /// Bytes, so that the plan stays protobuf-free.
  std::string candidate_template;
};

/// One alternative per job kind.
using JobKindPlan = std::variant<ChaosGamePlan, IfsMatrixPlan, SetIfsPlan, FractalFieldPlan,
                                 JellyPlan, ExplorePlan>;

/// @brief The units a job's iterating phase counts, for progress.
struct WorkPlan {
  uint64_t total = 0;
  /// "points", "set iterations", "pages", ...
  std::string unit;
};

/// @brief A validated job.
struct JobPlan {
  std::string name;
  GridFrame frame;
  DensityOptions density;
  JobKindPlan kind;
  WorkPlan work;
  std::vector<std::string> warnings;
  /// Largest singular value of each map's affine part (point IFS kinds).
  std::vector<double> contraction_factors;

  // Typed access for callers that know the kind; null otherwise.
  const ChaosGamePlan* chaos_game() const { return std::get_if<ChaosGamePlan>(&kind); }
  const IfsMatrixPlan* ifs_matrix() const { return std::get_if<IfsMatrixPlan>(&kind); }
  const SetIfsPlan* set_ifs() const { return std::get_if<SetIfsPlan>(&kind); }
  const FractalFieldPlan* fractal_field() const { return std::get_if<FractalFieldPlan>(&kind); }
  const JellyPlan* jelly() const { return std::get_if<JellyPlan>(&kind); }
  const ExplorePlan* explore() const { return std::get_if<ExplorePlan>(&kind); }
  /// The chaos game of a point-IFS job (plain, or the whole matrix
  /// selection); null for set IFS, fractal fields and jelly.
  const ChaosGameParams* point_run() const;
  /// The one chaos game a sharded job splits (docs/sharding.md): a plain
  /// chaos game, or an IFS matrix without a component grid; null otherwise.
  const ChaosGameParams* shardable_run() const;
  /// Whether the spec alone determines the result, so that a finished twin
  /// may answer for it (docs/result_cache.md): false for jelly, whose
  /// running jobs also take pokes.
  bool result_cacheable() const;
};

/// "chaos_game", "ifs_matrix", "set_ifs", "fractal_field", "jelly" or "explore": for logs
/// and messages.
std::string_view KindName(const JobKindPlan& kind);

}  // namespace nimbus
