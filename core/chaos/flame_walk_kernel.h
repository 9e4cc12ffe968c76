// @brief The body of flame::Round*, written once over an instruction-set
// description `Isa` and included by each kernel's translation unit after it
// has declared its vector operations (see variation_formulas.h). Isa has:
// T (doubles), kWidth (lanes per T); Load/Store; Index(const int32_t*)
// (kWidth walker or map indices), Gather(base, index) and Scatter(base,
// index, T) of doubles, GatherWord(base, index) and LoadWord(p) of random
// words, Uniform(word) and Bit(word) as the scalar Rng reads a word;
// Zero(); SortByMap, as SortByMapScalar below does it; and kStaged.
// Where kStaged is false: ToDouble(index), LookupMaps(table, maps, index)
// (Gather from a per-map table), DrawWords(walkers, n, words), which
// advances walkers [0, n) of their streams by `words` words each, and
// PickMaps, as PickMapsScalar below does it. Where it is true:
// DrawPickRecolor, those steps and Recolor in one pass; Stage, Unstage,
// and Pair, an Isa of two registers for runs of more than one register
// (see MapsStaged).
#pragma once

#include <algorithm>

#include "core/chaos/flame_walk.h"
#include "core/chaos/variation_formulas.h"

namespace nimbus::flame {
namespace {

// Where a map pass reads its lanes and writes them back. By walker index:
// gathers, and scatters to (ox, oy, oz); every gather comes before any
// scatter, so an index may repeat (padding).
template <class Isa>
struct ByIndex {
  decltype(Isa::Index(nullptr)) index;
  const double *x, *y, *z;
  double *ox, *oy, *oz;
  const uint64_t* words;  // the map's first word column, kMaxWalkers apart
  formulas::P3<typename Isa::T> In() const {
    return {Isa::Gather(x, index), Isa::Gather(y, index), Isa::Gather(z, index)};
  }
  void Out(const formulas::P3<typename Isa::T>& q) const {
    Isa::Scatter(ox, index, q.x);
    Isa::Scatter(oy, index, q.y);
    Isa::Scatter(oz, index, q.z);
  }
  auto Word(uint32_t c) const { return Isa::GatherWord(words + size_t(c) * kMaxWalkers, index); }
};

// Whole registers: lanes read at x, y, z and written at ox, oy, oz; word
// column c at words + c * stride. kPlanar (Program::planar): z is neither
// read (+0 stands in: its coefficients are zeros) nor written (it is +0).
template <class Isa, bool kPlanar = false>
struct Contiguous {
  const double *x, *y, *z;
  double *ox, *oy, *oz;
  const uint64_t* words;
  size_t stride;
  formulas::P3<typename Isa::T> In() const {
    return {Isa::Load(x), Isa::Load(y), kPlanar ? Isa::Zero() : Isa::Load(z)};
  }
  void Out(const formulas::P3<typename Isa::T>& q) const {
    Isa::Store(ox, q.x), Isa::Store(oy, q.y);
    if constexpr (!kPlanar) Isa::Store(oz, q.z);
  }
  auto Word(uint32_t c) const { return Isa::LoadWord(words + c * stride); }
};

// The pre-drawn words of one term, in order.
template <class Isa, class Access>
struct WordDraws {
  const Access& at;
  uint32_t next;
  typename Isa::T Uniform() { return Isa::Uniform(at.Word(next++)); }
  auto Bit() { return Isa::Bit(at.Word(next++)); }
};

// p -> A p + b with one map's coefficients, in Affine3::Apply's order.
template <class T>
inline formulas::P3<T> ApplyAffine(const double* a, const formulas::P3<T>& p) {
  auto row = [&](int r) {
    return a[4 * r] * p.x + a[4 * r + 1] * p.y + a[4 * r + 2] * p.z + a[4 * r + 3];
  };
  return {row(0), row(1), row(2)};
}

// Map m of `t` on one register of lanes, read and written through `at`.
template <class Isa, class Access>
inline void ApplyMap(const MapTables& t, uint32_t m, const Access& at) {
  using T = typename Isa::T;
  using formulas::P3;
  const double* pre = t.pre + 12 * size_t(m);
  P3<T> q = ApplyAffine<T>(pre, at.In());
  if (t.has_terms[m]) {
    P3<T> sum{Isa::Zero(), Isa::Zero(), Isa::Zero()};
    for (uint32_t j = t.first_term[m]; j < t.first_term[m + 1]; ++j) {
      const Term& term = t.terms[j];
      WordDraws<Isa, Access> draws{at, term.draw};
      const P3<T> v = formulas::Variation<T>(VariationKind(term.kind), q, pre, draws);
      sum = {sum.x + term.weight * v.x, sum.y + term.weight * v.y, sum.z + term.weight * v.z};
    }
    q = sum;
  }
  if (t.has_post[m]) q = ApplyAffine<T>(t.post + 12 * size_t(m), q);
  at.Out(q);
}

// AliasTable::Sample on word 0 of each walker, without a branch (a
// mispredicted coin flip per walker otherwise).
inline void PickMapsScalar(const Program& p, Walkers& w, int n) {
  const uint64_t num = p.maps.num_maps;
  for (int k = 0; k < n; ++k) {
    const uint64_t r = w.words[k];
    const uint32_t i = uint32_t(((r >> 32) * num) >> 32);
    const uint32_t keep = 0u - uint32_t(uint32_t(r) < p.threshold[i]);
    w.map[k] = (i & keep) | (p.alias[i] & ~keep);
  }
}

// ChaosGame's Recolor, kWidth walkers at a time.
template <class Isa>
inline void Recolor(const Program& p, Walkers& w, int n) {
  using T = typename Isa::T;
  for (int k = 0; k < n; k += Isa::kWidth) {
    const auto m = Isa::Index(reinterpret_cast<const int32_t*>(w.map + k));
    const T addr = (Isa::ToDouble(m) + Isa::Load(w.addr + k)) * p.inv_maps;
    Isa::Store(w.addr + k, addr);
    const T target = p.color_mode == 2 ? addr : Isa::LookupMaps(p.maps.color, p.maps.num_maps, m);
    const T col = Isa::Load(w.col + k);
    Isa::Store(w.col + k, col + p.blend * (target - col));
  }
}

// Counting sort of walkers [0, n) by map into w.order; group[m] is where
// map m's walkers begin, group[num_maps] = n.
inline void SortByMapScalar(uint32_t num_maps, Walkers& w, int n) {
  uint32_t* start = w.group;
  std::fill(start, start + num_maps + 1, 0u);
  for (int k = 0; k < n; ++k) ++start[w.map[k] + 1];
  for (uint32_t m = 0; m < num_maps; ++m) start[m + 1] += start[m];
  for (int k = n - 1; k >= 0; --k) w.order[--start[w.map[k] + 1]] = k;
  // Placing from the back leaves start[m + 1] at map m's first walker.
  for (uint32_t m = 0; m < num_maps; ++m) start[m] = start[m + 1];
  start[num_maps] = uint32_t(n);
}

// The maps by walker index: walkers sorted by map, each map's walkers
// gathered a register at a time.
template <class Isa>
void MapsByIndex(const Program& p, Walkers& w, int n) {
  constexpr int kW = Isa::kWidth;
  Isa::SortByMap(p.maps.num_maps, w, n);
  const uint64_t* map_words = w.words + kMaxWalkers;  // word 1
  auto apply = [&](uint32_t m, const int32_t* lanes) {
    const ByIndex<Isa> at{Isa::Index(lanes), w.x, w.y, w.z, w.x, w.y, w.z, map_words};
    ApplyMap<Isa>(p.maps, m, at);
  };
  for (uint32_t m = 0; m < p.maps.num_maps; ++m) {
    const int begin = int(w.group[m]), end = int(w.group[m + 1]);
    int k = begin;
    for (; k + kW <= end; k += kW) apply(m, w.order + k);
    if (k < end) {  // the last walker repeated to a whole register
      int32_t lanes[kW];
      for (int i = 0; i < kW; ++i) lanes[i] = w.order[std::min(k + i, end - 1)];
      apply(m, lanes);
    }
  }
}

// The maps staged: Isa::Stage copies each map's walkers, in walker order,
// into a run of Walkers::sx..., whose registers hold exactly the lanes
// MapsByIndex's would (the last walker repeated), so every lane computes
// the same bits; Isa::Unstage puts the results back. Two registers of a
// run go through the map together (Isa::Pair): each lane's operations are
// the same, and the halves' long-latency chains overlap.
// A planar program's runs leave z out: Unstage stores +0.
template <class Isa, bool kPlanar>
void MapsStaged(const Program& p, Walkers& w, int n) {
  constexpr int kW = Isa::kWidth;
  Isa::Stage(p.maps, w, n, kPlanar);
  using Pair = typename Isa::Pair;
  for (uint32_t m = 0; m < p.maps.num_maps; ++m) {
    const uint32_t end = w.stage_end[m];
    for (uint32_t k = w.stage_begin[m]; k < end;) {
      double *x = w.sx + k, *y = w.sy + k, *z = w.sz + k;
      if (k + kW < end) {  // two registers of the run in one pass
        const Contiguous<Pair, kPlanar> at{x, y, z, x, y, z, &w.sw[0][k], kStage};
        ApplyMap<Pair>(p.maps, m, at);
        k += Pair::kWidth;
      } else {
        const Contiguous<Isa, kPlanar> at{x, y, z, x, y, z, &w.sw[0][k], kStage};
        ApplyMap<Isa>(p.maps, m, at);
        k += kW;
      }
    }
  }
  Isa::Unstage(p.maps.num_maps, w, n, kPlanar);
}

// Whether a program fits the staging room.
inline bool Stageable(const Program& p) {
  return p.maps.num_maps <= uint32_t(kStageMaps) && p.final_word - 1 <= uint32_t(kStageWords);
}

template <class Isa>
void RoundWith(const Program& p, Walkers& w, int n) {
  constexpr int kW = Isa::kWidth;
  if constexpr (Isa::kStaged) {
    Isa::DrawPickRecolor(p, w, n);
    if (Stageable(p) && p.planar)
      MapsStaged<Isa, true>(p, w, n);
    else if (Stageable(p))
      MapsStaged<Isa, false>(p, w, n);
    else
      MapsByIndex<Isa>(p, w, n);
  } else {
    Isa::DrawWords(w, n, p.words);
    Isa::PickMaps(p, w, n);
    if (p.color_mode != 0) Recolor<Isa>(p, w, n);
    MapsByIndex<Isa>(p, w, n);
  }
  if (p.final_map.num_maps == 0) return;
  const uint64_t* final_words = w.words + size_t(p.final_word) * kMaxWalkers;
  for (int k = 0; k < n; k += kW) {
    // Out of place: the plot reads the point after the final transform,
    // the next step the one before.
    const Contiguous<Isa> at{w.x + k,  w.y + k,  w.z + k,          w.fx + k,
                             w.fy + k, w.fz + k, final_words + k, kMaxWalkers};
    ApplyMap<Isa>(p.final_map, 0, at);
  }
}

}  // namespace
}  // namespace nimbus::flame
