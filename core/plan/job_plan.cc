#include "core/plan/job_plan.h"

namespace nimbus {

namespace {
// Overload set for std::visit.
template <class... Fs>
struct Overloaded : Fs... {
  using Fs::operator()...;
};
template <class... Fs>
Overloaded(Fs...) -> Overloaded<Fs...>;
}  // namespace

const ChaosGameParams* JobPlan::point_run() const {
  return std::visit(Overloaded{[](const ChaosGamePlan& p) { return &p.params; },
                               [](const IfsMatrixPlan& p) { return &p.run; },
                               [](const SetIfsPlan&) -> const ChaosGameParams* { return nullptr; }},
                    kind);
}

std::string_view KindName(const JobKindPlan& kind) {
  return std::visit(Overloaded{[](const ChaosGamePlan&) { return "chaos_game"; },
                               [](const IfsMatrixPlan&) { return "ifs_matrix"; },
                               [](const SetIfsPlan&) { return "set_ifs"; }},
                    kind);
}

}  // namespace nimbus
