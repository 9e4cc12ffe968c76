// @brief The spec of one explorer candidate (docs/explore.md): a plain
// chaos_game job that draws the candidate's thumbnail big, and its volume
// for solid IFS.
#pragma once

#include <string>

#include "absl/status/statusor.h"
#include "core/chaos/ifs_explorer.h"
#include "nimbus/v1/spec.pb.h"

namespace nimbus::spec {

/// The template (ExplorePlan::candidate_template, made by the spec
/// converter) with the candidate's maps as 12-number matrices, its
/// variations, its walk seed and its fitted box as the grid bounds, named
/// `name`. Submitting it renders the thumbnail's attractor with the same
/// framing (looking down -z).
absl::StatusOr<v1::JobSpec> ExploreCandidateSpec(const std::string& template_bytes,
                                                 const ExploreCandidate& candidate,
                                                 const std::string& name);

}  // namespace nimbus::spec
