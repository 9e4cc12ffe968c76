// @brief The body of flame::ApplyMaps*, written once over an instruction-set
// description `Isa` and included by each kernel's translation unit after it
// has declared its vector operations (see variation_formulas.h). Isa has:
// T (the number type) and kWidth (lanes per T); Load/Store; Index(map) (a
// lane's row in the 12-wide tables) and Gather(table, index, j); Zero();
// MapIs(map, m) (the lanes whose map is m) and Any(mask).
#pragma once

#include "core/chaos/flame_walk.h"
#include "core/chaos/variation_formulas.h"

namespace nimbus::flame {
namespace {

// Pre-drawn numbers of one term, read column by column.
template <class Isa>
struct ColumnDraws {
  const double* next;
  typename Isa::T Uniform() {
    const typename Isa::T v = Isa::Load(next);
    next += kSlots;
    return v;
  }
  auto Bit() { return formulas::IsPositive(Uniform()); }
};

// p -> A p + b with each lane's own coefficients, in Affine3::Apply's order.
template <class Isa, class I, class T = typename Isa::T>
inline formulas::P3<T> ApplyAffine(const double* table, const I& index, const formulas::P3<T>& p) {
  auto row = [&](int r) {
    return Isa::Gather(table, index, 4 * r) * p.x + Isa::Gather(table, index, 4 * r + 1) * p.y +
           Isa::Gather(table, index, 4 * r + 2) * p.z + Isa::Gather(table, index, 4 * r + 3);
  };
  return {row(0), row(1), row(2)};
}

template <class M, class T>
inline formulas::P3<T> SelectP3(const M& m, const formulas::P3<T>& a, const formulas::P3<T>& b) {
  using formulas::Select;
  return {Select(m, a.x, b.x), Select(m, a.y, b.y), Select(m, a.z, b.z)};
}

template <class Isa>
void ApplyMapsWith(const MapTables& t, Batch& b) {
  using T = typename Isa::T;
  using formulas::P3;
  for (int g = 0; g < b.count; g += Isa::kWidth) {
    const int64_t* map = b.map + g;
    const auto index = Isa::Index(map);
    const P3<T> p{Isa::Load(b.x + g), Isa::Load(b.y + g), Isa::Load(b.z + g)};
    P3<T> q = ApplyAffine<Isa>(t.pre, index, p);
    // The weighted sum, each lane over its own map's terms in their order.
    P3<T> sum{Isa::Zero(), Isa::Zero(), Isa::Zero()};
    for (uint32_t i = 0; i < t.num_terms; ++i) {
      const Term& term = t.terms[i];
      const auto active = Isa::MapIs(map, term.map);
      if (!Isa::Any(active)) continue;
      ColumnDraws<Isa> draws{b.draws + size_t(term.draw) * kSlots + g};
      const P3<T> v =
          formulas::Variation<T>(VariationKind(term.kind), q, t.pre + 12 * size_t(term.map), draws);
      const P3<T> added{sum.x + term.weight * v.x, sum.y + term.weight * v.y,
                        sum.z + term.weight * v.z};
      sum = SelectP3(active, added, sum);
    }
    q = SelectP3(formulas::IsPositive(Isa::Gather(t.has_terms, index, 0)), sum, q);
    const auto post = formulas::IsPositive(Isa::Gather(t.has_post, index, 0));
    if (Isa::Any(post)) q = SelectP3(post, ApplyAffine<Isa>(t.post, index, q), q);
    Isa::Store(b.x + g, q.x);
    Isa::Store(b.y + g, q.y);
    Isa::Store(b.z + g, q.z);
  }
}

}  // namespace
}  // namespace nimbus::flame
