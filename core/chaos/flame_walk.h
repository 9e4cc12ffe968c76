// @brief The nonlinear (flame) maps applied to a batch of walkers at once:
// every walker's pre-affine, weighted variation sum and post-affine, in
// structure-of-arrays form. One formula source (variation_formulas.h) is
// compiled three times: portably with the C library's functions (the
// scalar reference) and for AVX2 and AVX-512 with SLEEF's vector functions;
// core/base/cpu_dispatch.h picks one at run time. docs/chaos_game.md states
// which kernels agree bit for bit and which within an ulp bound.
//
// Plain data only, like affine_walk.h: the SIMD translation units include
// nothing else of the engine.
#pragma once

#include <cstdint>

namespace nimbus::flame {

/// Slots of a batch: room for a chunk's 16 walkers grouped by map, each
/// group padded to a whole AVX-512 register (8 slots), so that a register
/// mostly holds walkers of one map and evaluates only that map's terms.
inline constexpr int kSlots = 32;
/// Slots are processed in multiples of this.
inline constexpr int kSlotAlign = 8;

/// @brief One weighted variation term of one map. Terms are listed map by
/// map, each map's in its own order, so a walker sums its terms in the
/// order the scalar engine does. `draw` is the first column of the batch's
/// pre-drawn random numbers this term reads (formulas::VariationDraws).
struct Term {
  uint32_t map = 0;
  uint32_t kind = 0;  // a VariationKind
  double weight = 0;
  uint32_t draw = 0;
};

/// @brief The maps as flat tables of 12 doubles per map: the pre-affine and
/// the post-affine (the identity where a map has none) as row-major [A | b],
/// and two flags (1 or 0, in the first of the map's 12 entries) so that one
/// gather index serves every table.
struct MapTables {
  const double* pre = nullptr;
  const double* post = nullptr;
  const double* has_post = nullptr;
  const double* has_terms = nullptr;
  const Term* terms = nullptr;
  uint32_t num_terms = 0;
};

/// @brief A batch: positions, each slot's map (an index into the tables)
/// and its pre-drawn random numbers, draws[column * kSlots + slot]. Slots
/// [0, count) are applied, count a multiple of kSlotAlign; padding slots
/// need only a valid map.
struct alignas(64) Batch {
  double x[kSlots], y[kSlots], z[kSlots];
  int64_t map[kSlots];
  int count = 0;
  const double* draws = nullptr;
};

/// Replaces every slot's position by its map's image.
using ApplyMapsFn = void (*)(const MapTables& t, Batch& b);
void ApplyMapsScalar(const MapTables& t, Batch& b);
/// AVX2 (4 lanes per register) and AVX-512 (8 lanes per register) with
/// SLEEF; call only where the CPU has them.
void ApplyMapsAvx2(const MapTables& t, Batch& b);
void ApplyMapsAvx512(const MapTables& t, Batch& b);

}  // namespace nimbus::flame
