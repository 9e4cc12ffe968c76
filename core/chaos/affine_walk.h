// The chaos game's hot loop for plain affine IFS that only count visits:
// many walkers in structure-of-arrays form, each plotted point's voxel
// pushed straight into per-tile bins. Scalar, AVX2 and AVX-512 versions give
// bitwise-identical walks; core/cpu_dispatch.h picks one at run time.
//
// Everything here is plain data: the AVX2 translation unit includes only
// this header, because an inline function compiled there with AVX2 enabled
// could be the copy the linker keeps for the rest of the program.
#pragma once

#include <cstdint>

namespace nimbus::walk {

/// Walkers advanced together: four AVX2 groups of four doubles, enough
/// independent chains to hide the latency of one step.
inline constexpr int kLanes = 16;

/// @brief Walker state as structure of arrays: positions, the four words
/// of each walker's own xoshiro256++ stream (the same generator as Rng) and,
/// for a Markov chain, the walker's state.
struct alignas(64) Walkers {
  double x[kLanes], y[kLanes], z[kLanes];
  uint64_t s0[kLanes], s1[kLanes], s2[kLanes], s3[kLanes];
  uint64_t state[kLanes];
};

/// @brief A Markov chain over the maps (ChaosGame's MarkovChain) as flat
/// tables of packed 64-bit words, so the AVX2 kernel needs one gather per
/// table. State s owns transitions [offset, offset + count), with
/// state[s] = offset | count << 32; they are sampled with their own alias
/// table, sample[t] = threshold | alias << 32 (alias indexed within the
/// state). Taking transition t applies a map and moves to a state:
/// step[t] = map | plotted << 31 | next << 32, where `plotted` says whether
/// points in the next state are plotted.
struct ChainTables {
  const uint64_t* state = nullptr;
  const uint64_t* sample = nullptr;
  const uint64_t* step = nullptr;
};

/// Write position and end of one bin's current block. A push with
/// tail == end first asks the owner for a new block.
struct BinCursor {
  uint32_t* tail = nullptr;
  uint32_t* end = nullptr;
};

/// @brief What the kernels read. Points either increment their voxel at once
/// (direct mode: `tiles` set) or are binned by tile: bin = tile >> bin_shift,
/// and a bin entry is (tile & (2^bin_shift - 1)) << 15 | the voxel's offset
/// in its tile (CountGrid::LocalOffset).
struct AffineWalk {
  const double* coef = nullptr;         // 12 per map: the rows of [A | b]
  const uint32_t* threshold = nullptr;  // alias table (AliasTable); unused with a chain
  const uint32_t* alias = nullptr;
  uint32_t num_maps = 0;
  /// When set, maps are drawn by the chain instead of the alias table.
  const ChainTables* chain = nullptr;
  /// Every map's z row is (0, 0, 0, c) with the same c, and z's column in
  /// the x and y rows is 0: z is c after every step, whatever x and y
  /// (a 2D IFS). Kernels may then skip z, which changes nothing but the
  /// sign of a zero x or y (no voxel depends on it) and leaves Walkers::z
  /// stale (finite: restarted walkers are warmed up by the owner).
  bool planar = false;
  double min[3] = {0, 0, 0};        // grid bounds' minimum corner
  double inv_voxel[3] = {1, 1, 1};  // voxels per world unit
  double res[3] = {0, 0, 0};        // resolution, as doubles
  uint32_t tiles_y = 0, tiles_z = 0;
  uint32_t bin_shift = 0;
  /// Image rows folded into the tile's depth (ImagePlane): voxel y becomes
  /// (y >> fold_shift, z + (y & fold_mask)). 0 and 0 for a volume.
  uint32_t fold_mask = 0, fold_shift = 0;
  BinCursor* bins = nullptr;
  /// Direct mode: tiles[t] is tile t's counters, null until `allocate`
  /// returns them (and stores them in tiles[t]).
  uint32_t** tiles = nullptr;
  /// Flat direct mode (instead of `tiles`, small lattices): one counter
  /// per lattice voxel (ix, iy, iz) of `res`, before any fold, at
  /// flat[(ix * res.y + iy) * res.z + iz] (flat_stride = {res.y, res.z}):
  /// two multiply-adds instead of the tile and leaf arithmetic and a table
  /// lookup (TileBins' flat mode). Lanes that add nothing may increment
  /// flat[flat_discard] instead.
  uint32_t* flat = nullptr;
  uint32_t flat_stride[2] = {0, 0};
  uint32_t flat_discard = 0;
  void* owner = nullptr;
  uint32_t* (*allocate)(void* owner, uint32_t tile) = nullptr;
  /// bins[bin] is full (or has no block yet): give it room for one entry.
  void (*refill)(void* owner, uint32_t bin) = nullptr;
  /// The lane's new point is not finite, or is to be plotted but lies
  /// outside the grid box. The owner may restart the walker by rewriting
  /// its lane of Walkers.
  void (*exit)(void* owner, int lane) = nullptr;
};

namespace {

// The SIMD kernels' last stage for lanes [g, g + n) of one register, given
// bit masks of the lanes whose point is to be plotted, is finite and lies
// inside the grid: a lane not plotted only reports a non-finite point, a
// plotted one outside the grid reports, the rest push their bin entry.
// Internal linkage: each SIMD file keeps its own copy (see above).
inline void PushLanes(const AffineWalk& k, int g, int n, int plot, int finite, int inside,
                      const uint32_t* bin, const uint32_t* entry) {
  const int all = (1 << n) - 1;
  if ((plot & inside & all) == all) [[likely]] {
    // Every lane pushes: no per-lane tests, and the cursor table in a
    // local (a store through a cursor could otherwise alias k.bins).
    BinCursor* bins = k.bins;
    for (int l = 0; l < n; ++l) {
      BinCursor& cur = bins[bin[l]];
      if (cur.tail == cur.end) [[unlikely]]
        k.refill(k.owner, bin[l]);
      *cur.tail++ = entry[l];
    }
    return;
  }
  for (int l = 0; l < n; ++l) {
    if (!((plot >> l) & 1)) {
      if (!((finite >> l) & 1)) [[unlikely]]
        k.exit(k.owner, g + l);
      continue;
    }
    if (!((inside >> l) & 1)) [[unlikely]] {
      k.exit(k.owner, g + l);
      continue;
    }
    BinCursor& cur = k.bins[bin[l]];
    if (cur.tail == cur.end) [[unlikely]]
      k.refill(k.owner, bin[l]);
    *cur.tail++ = entry[l];
  }
}

// Exits of lanes [g, g + n): the lanes not plotted whose point is not
// finite, and the plotted ones outside the grid.
inline void ExitLanes(const AffineWalk& k, int g, int n, int plot, int finite, int inside) {
  const int all = (1 << n) - 1;
  int out = ((plot & ~inside) | (~plot & ~finite)) & all;
  for (; out; out &= out - 1) k.exit(k.owner, g + __builtin_ctz(unsigned(out)));
}

// Direct mode's last stage: each lane plotted inside the grid increments
// its voxel (tile[l], local[l]) where it lies; the rest may exit.
inline void AddLanes(const AffineWalk& k, int g, int n, int plot, int finite, int inside,
                     const uint32_t* tile, const uint32_t* local) {
  const int all = (1 << n) - 1;
  if ((plot & inside & all) != all) [[unlikely]] {
    ExitLanes(k, g, n, plot, finite, inside);
    for (int l = 0; l < n; ++l) {
      if (!((plot & inside) >> l & 1)) continue;
      uint32_t* t = k.tiles[tile[l]];
      if (!t) [[unlikely]]
        t = k.allocate(k.owner, tile[l]);
      ++t[local[l]];
    }
    return;
  }
  for (int l = 0; l < n; ++l) {
    uint32_t* t = k.tiles[tile[l]];
    if (!t) [[unlikely]]
      t = k.allocate(k.owner, tile[l]);
    ++t[local[l]];
  }
}

// Flat direct mode's last stage: lanes plotted inside the grid increment
// flat[index[l]] (their lattice index); the rest may exit.
inline void AddFlatLanes(const AffineWalk& k, int g, int n, int plot, int finite, int inside,
                         const uint32_t* index) {
  const int all = (1 << n) - 1;
  if ((plot & inside & all) != all) [[unlikely]] {
    ExitLanes(k, g, n, plot, finite, inside);
    for (int l = 0; l < n; ++l)
      if ((plot & inside) >> l & 1) ++k.flat[index[l]];
    return;
  }
  for (int l = 0; l < n; ++l) ++k.flat[index[l]];
}

}  // namespace

/// Advances every lane by `steps` plotted steps.
void WalkScalar(const AffineWalk& k, Walkers& w, uint64_t steps);
/// Same walk with AVX2; call only where the CPU has AVX2.
void WalkAvx2(const AffineWalk& k, Walkers& w, uint64_t steps);
/// Same walk with AVX-512 (F and DQ); call only where the CPU has them.
void WalkAvx512(const AffineWalk& k, Walkers& w, uint64_t steps);
/// Advances one lane by `steps` plotted steps.
void WalkLane(const AffineWalk& k, Walkers& w, int lane, uint64_t steps);

}  // namespace nimbus::walk
