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
  using Run = const ChaosGameParams*;
  return std::visit(
      Overloaded{// Pictures and auto-framing run extra passes the shard runner does not.
                 [](const ChaosGamePlan& p) -> Run {
                   return p.image || p.auto_frame ? nullptr : &p.params;
                 },
                 // A component grid runs one game per component and keeps their labels.
                 [](const IfsMatrixPlan& p) -> Run {
                   return p.component_grid != ComponentGridType::kNone ? nullptr : &p.run;
                 },
                 [](const SetIfsPlan&) -> Run { return nullptr; },
                 [](const FractalFieldPlan&) -> Run { return nullptr; },
                 [](const JellyPlan&) -> Run { return nullptr; },
                 [](const ExplorePlan&) -> Run { return nullptr; }},
      kind);
}

bool JobPlan::result_cacheable() const {
  return std::visit(Overloaded{[](const ChaosGamePlan&) { return true; },
                               [](const IfsMatrixPlan&) { return true; },
                               [](const SetIfsPlan&) { return true; },
                               [](const FractalFieldPlan&) { return true; },
                               [](const JellyPlan&) { return false; },
                               [](const ExplorePlan&) { return true; }},
                    kind);
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
