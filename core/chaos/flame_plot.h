// @brief The flame path's plotting, for a whole round of walkers at once:
// each walker's point (after the final transform, when there is one) is
// projected onto the grid or the picture, tested against its bounds and
// packed into a CountGrid key with the walker's colour bits. The scalar
// kernel is the reference; the AVX2 and AVX-512 kernels compute the same
// keys bit for bit (no FMA contraction, only correctly rounded operations),
// which is ChaosGame's one-point-at-a-time Plot for grids and pictures.
//
// Plain data only, like flame_walk.h: the SIMD translation units include
// nothing else of the engine.
#pragma once

#include <cstdint>

#include "core/chaos/flame_walk.h"

namespace nimbus::flame {

/// @brief Where points are counted and how a voxel becomes a key
/// (CountGrid::Key, with ImagePlane::Voxel's fold for pictures).
struct PlotTarget {
  enum Kind : uint32_t { kGrid = 0, kOrtho = 1, kPerspective = 2 };
  uint32_t kind = kGrid;
  /// kGrid: voxel coordinates (q - min) * inv_voxel.
  double min[3] = {0, 0, 0};
  double inv_voxel[3] = {1, 1, 1};
  /// Pictures: c = view * q (12 row-major doubles [A | b], Affine3::Apply's
  /// order); kOrtho keeps 0 <= c.z < 1 and plots (c.x, c.y); kPerspective
  /// keeps c.z > near and plots (cx + focal c.x / c.z, cy - focal c.y / c.z).
  double view[12] = {};
  double focal = 0, cx = 0, cy = 0, near = 0;
  /// kOrtho with an axis-aligned view: view[1], [2], [4], [6], [8] and [9]
  /// are 0, so c = (view[0] x + view[3], view[5] y + view[7], view[10] z +
  /// view[11]) and the vector kernels skip the zero products. Those add
  /// only zeros, and wherever a key is kept the point is finite, so they
  /// could change at most the sign of a zero coordinate: never a key.
  bool axis_aligned = false;
  /// The lattice points must fall in: the grid's resolution, or (width,
  /// height, 1) for a picture.
  int32_t res[3] = {0, 0, 0};
  /// CountGrid's fold of voxel (x, y, z): stored at (x, y >> fold_shift,
  /// z + (y & fold_mask)); a picture's rows fold the same way (5 and 31).
  uint32_t fold_shift = 0, fold_mask = 0;
  /// Tiles of the stored layout along y and z.
  uint32_t tiles_y = 1, tiles_z = 1;
  /// Attach the walker's colour (CountGrid::WithColor of its rounded col).
  bool color = false;
  /// Every walker's z is +0 wherever its x and y are finite (a planar
  /// flame::Program without a final transform): the vector kernels take
  /// z as +0 instead of reading and testing it, with the same keys.
  bool planar = false;
};

/// Words of a Plotted mask.
inline constexpr int kMaskWords = kMaxWalkers / 64;

/// @brief One round's plot of walkers [0, n). Walker k is bit k % 64 of
/// word k / 64 of a mask; words past walker n - 1's are zero.
struct Plotted {
  alignas(64) uint64_t key[kMaxWalkers];  // valid where `inside` is set
  uint64_t inside[kMaskWords] = {};       // the point lands on the grid or picture
  uint64_t bad_walker[kMaskWords] = {};   // the walker's own point is not finite: restart it
  uint64_t bad_final[kMaskWords] = {};    // finite walker, non-finite plotted point
  /// Zeroes the masks (the keys are read only where `inside` is set).
  void ClearMasks() {
    for (int i = 0; i < kMaskWords; ++i) inside[i] = bad_walker[i] = bad_final[i] = 0;
  }
};

/// Plots walkers [0, n), n a multiple of kAlign; with `final_map` the
/// points are (fx, fy, fz), else (x, y, z).
using PlotFn = void (*)(const PlotTarget& t, const Walkers& w, bool final_map, int n,
                        Plotted* out);
void PlotScalar(const PlotTarget& t, const Walkers& w, bool final_map, int n, Plotted* out);
/// Same keys with AVX2 and AVX-512 (F, DQ); call only where the CPU has them.
void PlotAvx2(const PlotTarget& t, const Walkers& w, bool final_map, int n, Plotted* out);
void PlotAvx512(const PlotTarget& t, const Walkers& w, bool final_map, int n, Plotted* out);

}  // namespace nimbus::flame
