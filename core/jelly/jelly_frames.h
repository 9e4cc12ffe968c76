// @brief The frame loop's two halves, shared by the job runner, tests and
// the benchmark: advance the physics to the next frame (impulses, pokes,
// fixed substeps) and turn a frame's maps into leaves that stay above the
// ground.
#pragma once

#include <cstdint>
#include <vector>

#include "absl/status/statusor.h"
#include "core/base/interrupter.h"
#include "core/jelly/jelly_plan.h"
#include "core/jelly/jelly_world.h"

namespace nimbus {

/// Gives `poke` to the world: an impulse at once, or a drag lasting its
/// frames (× substeps steps).
void ApplyPoke(JellyWorld& world, const JellyPoke& poke, uint32_t substeps);

/// Steps from frame `frame - 1` to frame `frame` (>= 1): first the spec's
/// impulses for this frame, then `pokes` (in order), then plan.substeps
/// steps. CANCELLED when interrupted (polled once per ~1024 steps).
absl::Status AdvanceFrame(JellyWorld& world, const JellyPlan& plan, uint64_t frame,
                          const std::vector<JellyPoke>& pokes, Interrupter* interrupter);

/// The frame's leaves from the world's current maps, moved up onto the
/// ground plane when there is one. Returns how many were moved.
absl::StatusOr<uint64_t> FrameLeaves(const JellyWorld& world, const JellyPlan& plan,
                                     std::vector<Vec3>& leaves, Interrupter* interrupter);

}  // namespace nimbus
