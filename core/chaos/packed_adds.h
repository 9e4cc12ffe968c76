// @brief The inner loops of KeyBins' packed words (key_bins.h), one set per
// instruction-set level, picked at run time (base/cpu_dispatch.h):
//
//   const packed::Loops& loops = packed::LoopsFor(ActiveSimd());
//   uint32_t n = loops.hold(words, key, lanes, hold);  // this round's keys
//   ...                                                 // a kernel round later
//   touched |= loops.apply(words, hold, n, weighted);
//
// A word is one voxel's visit count (from bit kCountShift) and colour sum.
// Every level adds the same integers, so the words end up the same.
#pragma once

#include <cstdint>

#include "core/base/cpu_dispatch.h"

namespace nimbus::packed {

/// A word's count starts at this bit; its colour sum lies below.
inline constexpr int kCountShift = 40;

/// Room for a round's held keys: up to four calls of `hold`, each
/// appending at most 64 keys. (The vector loops store whole registers, but
/// register r of a call's lanes lands at r or lower past where the call
/// began, so no store reaches past 64 per call.)
inline constexpr int kHoldRoom = 256;

struct Loops {
  /// Copies key[i] for every set bit i of `lanes` (at most 64), in lane
  /// order, into `hold`; requests each key's word for writing; returns how
  /// many.
  uint32_t (*hold)(const uint64_t* words, const uint64_t* key, uint64_t lanes, uint64_t* hold);
  /// Adds the `n` keys of `held` to their words: weight w (1 unless
  /// `weighted`) adds w to the count and w times the key's colour to the
  /// sum. Returns the tiles touched (bit t: voxels [t 2^15, (t + 1) 2^15)).
  uint64_t (*apply)(uint64_t* words, const uint64_t* held, uint32_t n, bool weighted);
};

/// The loops for `level` (AVX2 takes the scalar ones: it has no compress).
const Loops& LoopsFor(SimdLevel level);

// The AVX-512 loops (packed_adds_avx512.cc); call only where the CPU has them.
const Loops& LoopsAvx512();

}  // namespace nimbus::packed
