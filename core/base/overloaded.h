// @brief An overload set of lambdas for std::visit: one lambda per
// alternative, so a variant that gains an alternative fails to compile
// where it is not handled.
//
//   std::visit(Overloaded{[](const A&) { ... }, [](const B&) { ... }}, v);
#pragma once

namespace nimbus {

template <class... Fs>
struct Overloaded : Fs... {
  using Fs::operator()...;
};
template <class... Fs>
Overloaded(Fs...) -> Overloaded<Fs...>;

}  // namespace nimbus
