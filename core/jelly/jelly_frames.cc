#include "core/jelly/jelly_frames.h"

#include "core/jelly/jelly_render.h"

namespace nimbus {

void ApplyPoke(JellyWorld& world, const JellyPoke& poke, uint32_t substeps) {
  if (poke.kind == JellyPoke::Kind::kImpulse)
    world.ApplyImpulse(poke.body, poke.vector);
  else
    world.AddDrag(poke.body, poke.vector, poke.stiffness, uint64_t(poke.frames) * substeps);
}

absl::Status AdvanceFrame(JellyWorld& world, const JellyPlan& plan, uint64_t frame,
                          const std::vector<JellyPoke>& pokes, Interrupter* interrupter) {
  for (const JellyPoke& p : plan.impulses)
    if (p.frame == frame) ApplyPoke(world, p, plan.substeps);
  for (const JellyPoke& p : pokes) ApplyPoke(world, p, plan.substeps);
  for (uint32_t s = 0; s < plan.substeps; ++s) {
    // A step is at most ~50 µs (256 bodies, all pairs): poll every 64.
    if ((s & 63) == 0 && OrNull(interrupter).WasInterrupted(frame, plan.frames))
      return absl::CancelledError("interrupted");
    world.Step();
  }
  return absl::OkStatus();
}

absl::StatusOr<uint64_t> FrameLeaves(const JellyWorld& world, const JellyPlan& plan,
                                     std::vector<Vec3>& leaves, Interrupter* interrupter) {
  if (absl::Status st = JellyLeaves(world.Maps(), plan.render, leaves, interrupter); !st.ok())
    return st;
  return plan.sim.ground.enabled ? ClampToGround(leaves, plan.sim.ground.height) : 0;
}

}  // namespace nimbus
