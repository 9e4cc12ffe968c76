// @brief The flame (nonlinear) walk, one round for a whole chunk of walkers
// at once: every walker's random words (its own xoshiro256++ stream), its
// map (the alias table), its recolouring, then walkers grouped by map so a
// register holds walkers of one map and evaluates that map's terms only:
// pre-affine, weighted variation sum, post-affine. The final transform is
// a second pass. One formula source (variation_formulas.h) is compiled three
// times: portably with the C library's functions (the scalar reference) and
// for AVX2 and AVX-512 with SLEEF's vector functions; core/base/cpu_dispatch.h
// picks one at run time. docs/chaos_game.md states which kernels agree bit
// for bit and which within an ulp bound.
//
// Plain data only, like affine_walk.h: the SIMD translation units include
// nothing else of the engine.
#pragma once

#include <cstdint>

namespace nimbus::flame {

/// Walkers a Walkers block holds; a round steps a multiple of kAlign.
/// ChaosGame fills a block with the walkers of up to four chunks (64
/// each): lanes are independent, so how many share a round changes no
/// walker's path, and bigger rounds leave less of each map's run padding
/// and spread a round's fixed costs over more steps.
inline constexpr int kMaxWalkers = 256;
inline constexpr int kAlign = 8;
/// Walkers of one chunk of a flame (ChaosGame::kChunkIterations steps),
/// each with its own random stream: fixed, as the paths depend on it.
inline constexpr int kChunkWalkers = 64;
/// The staged map pass (Walkers::sx) takes at most this many maps and
/// random words per map application; other programs go by walker index.
inline constexpr int kStageMaps = 8;
inline constexpr int kStageWords = 4;
/// Staging room: every map's run starts on a kAlign boundary, and loads
/// may run kAlign lanes past a run's end.
inline constexpr int kStage = kMaxWalkers + (kStageMaps + 1) * kAlign;

/// @brief One weighted variation term. `draw` is the first of the words the
/// term reads, counted from its map's first (formulas::VariationDraws).
struct Term {
  uint32_t kind = 0;  // a VariationKind
  double weight = 0;
  uint32_t draw = 0;
};

/// @brief A list of maps as flat tables: per map the pre-affine and the
/// post-affine (the identity where it has none) as 12 row-major doubles
/// [A | b], flags, its terms terms[first_term[m], first_term[m + 1]) in the
/// order a walker sums them, and its colour.
struct MapTables {
  const double* pre = nullptr;
  const double* post = nullptr;
  const uint8_t* has_post = nullptr;
  const uint8_t* has_terms = nullptr;
  const uint32_t* first_term = nullptr;
  const Term* terms = nullptr;
  const double* color = nullptr;
  uint32_t num_maps = 0;
  const uint32_t* words = nullptr;  // per map: the random words it reads
};

/// @brief What a round needs of the job. Each step a walker draws `words`
/// words: word 0 picks the map (AliasTable::Sample), words 1.. feed the
/// map's random terms, words final_word.. the final transform's.
struct Program {
  MapTables maps;
  MapTables final_map;                  // num_maps 0: none
  const uint32_t* threshold = nullptr;  // the alias table
  const uint32_t* alias = nullptr;
  uint32_t words = 1;
  uint32_t final_word = 1;
  int color_mode = 0;  // 0 none, 1 by map, 2 by address (ColorMode)
  double blend = 0;
  double inv_maps = 1;
  // Every step leaves z = +0 and x, y do not depend on z (FlameProgram::
  // Planar): a kernel may skip moving z and store +0 (AVX-512 staging).
  bool planar = false;
};

/// @brief The walkers of a chunk in structure-of-arrays form, with the
/// round's scratch. `words` holds Program::words x kMaxWalkers words
/// (word c of walker k at c * kMaxWalkers + k) and `group` num_maps + 1
/// entries, both owned by the caller.
struct alignas(64) Walkers {
  double x[kMaxWalkers], y[kMaxWalkers], z[kMaxWalkers];
  double addr[kMaxWalkers], col[kMaxWalkers];
  uint64_t s0[kMaxWalkers], s1[kMaxWalkers], s2[kMaxWalkers], s3[kMaxWalkers];
  // Written by a round: the point after the final transform (when there
  // is one), each walker's map, and the walkers sorted by map.
  double fx[kMaxWalkers], fy[kMaxWalkers], fz[kMaxWalkers];
  uint32_t map[kMaxWalkers];
  int32_t order[kMaxWalkers];
  uint64_t* words = nullptr;
  uint32_t* group = nullptr;
  // The staged map pass (AVX-512): each map's walkers copied into one run,
  // points and words, so the map reads and writes whole registers instead
  // of gathering and scattering by walker index. Run m is
  // [stage_begin[m], stage_end[m]), padded with its last walker to a whole
  // register.
  alignas(64) double sx[kStage], sy[kStage], sz[kStage];
  alignas(64) uint64_t sw[kStageWords][kStage];
  uint32_t stage_begin[kStageMaps], stage_end[kStageMaps];
};

/// One step of walkers [0, n), n a multiple of kAlign: draw, pick, recolour,
/// apply the maps, then the final transform (into fx, fy, fz) if any.
using RoundFn = void (*)(const Program& p, Walkers& w, int n);
void RoundScalar(const Program& p, Walkers& w, int n);
/// AVX2 (4 lanes per register) and AVX-512 (8 lanes) with SLEEF; call only
/// where the CPU has them.
void RoundAvx2(const Program& p, Walkers& w, int n);
void RoundAvx512(const Program& p, Walkers& w, int n);

}  // namespace nimbus::flame
