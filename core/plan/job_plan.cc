#include "core/plan/job_plan.h"

#include "core/base/overloaded.h"

namespace nimbus {

const ChaosGameParams* JobPlan::point_run() const {
  return std::visit(Overloaded{[](const ChaosGamePlan& p) { return &p.params; },
                               [](const IfsMatrixPlan& p) { return &p.run; },
                               [](const SetIfsPlan&) -> const ChaosGameParams* { return nullptr; },
                               [](const FractalFieldPlan&) -> const ChaosGameParams* {
                                 return nullptr;
                               },
                               [](const JellyPlan&) -> const ChaosGameParams* { return nullptr; },
                               [](const ExplorePlan&) -> const ChaosGameParams* {
                                 return nullptr;
                               }},
                    kind);
}

const ChaosGameParams* JobPlan::shardable_run() const {
  // A component grid runs one game per component and keeps their labels.
  if (const IfsMatrixPlan* m = ifs_matrix(); m && m->component_grid != ComponentGridType::kNone)
    return nullptr;
  // Pictures and auto-framing run extra passes the shard runner does not.
  if (const ChaosGamePlan* c = std::get_if<ChaosGamePlan>(&kind); c && (c->image || c->auto_frame))
    return nullptr;
  return point_run();
}

std::string_view KindName(const JobKindPlan& kind) {
  return std::visit(Overloaded{[](const ChaosGamePlan&) { return "chaos_game"; },
                               [](const IfsMatrixPlan&) { return "ifs_matrix"; },
                               [](const SetIfsPlan&) { return "set_ifs"; },
                               [](const FractalFieldPlan&) { return "fractal_field"; },
                               [](const JellyPlan&) { return "jelly"; },
                               [](const ExplorePlan&) { return "explore"; }},
                    kind);
}

}  // namespace nimbus
