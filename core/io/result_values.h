// How a result's voxel values come from its counts, shared by the OpenVDB
// module's writers (vdb_io.cc) and the native one (vdb_native_result.cc) so
// both compute the same floats: the density mapping and the gathering of
// one 8^3 leaf's counters.
#pragma once

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstring>

#include "core/grid/count_grid.h"
#include "core/io/vdb_io.h"

namespace nimbus {

inline const char* MappingName(DensityMapping m) {
  switch (m) {
    case DensityMapping::kLinear:
      return "linear";
    case DensityMapping::kSqrt:
      return "sqrt";
    case DensityMapping::kLog:
      return "log";
    case DensityMapping::kGamma:
      return "gamma";
  }
  return "linear";
}

// Maps a count to [0, 1] given the largest count.
struct Normaliser {
  DensityMapping mapping;
  double max, inv_max, inv_log_max, inv_gamma;
  Normaliser(const DensityOptions& o, uint32_t max_count)
      : mapping(o.mapping),
        max(std::max<double>(1, max_count)),
        inv_max(1.0 / max),
        inv_log_max(1.0 / std::log1p(max)),
        inv_gamma(1.0 / (o.gamma > 0 ? o.gamma : 1.0)) {}
  float operator()(uint32_t c) const {
    switch (mapping) {
      case DensityMapping::kLinear:
        return float(c * inv_max);
      case DensityMapping::kSqrt:
        return float(std::sqrt(c * inv_max));
      case DensityMapping::kLog:
        return float(std::log1p(double(c)) * inv_log_max);
      case DensityMapping::kGamma:
        return float(std::pow(c * inv_max, inv_gamma));
    }
    return 0.f;
  }
};

// The 512 counters (and colour sums, when `cs`) of the voxel leaf at `o`,
// in LeafNode order, as CountGrid::ForEachLeaf hands them out. With
// `active` (the leaf's value mask), a folded grid fills only those voxels
// and leaves the rest as they were, instead of zeroing 6 KiB per leaf.
inline void GatherCountLeaf(const CountGrid& counts, Int3 o, uint32_t* v, uint64_t* cs,
                            const uint64_t* active = nullptr) {
  if (!counts.folded()) {
    // Unfolded, a voxel leaf is 512 consecutive counters of one tile.
    const uint64_t key = counts.Key(o.x, o.y, o.z);
    const uint64_t tile = key >> 15, off = key & 0x7fff;
    std::memcpy(v, counts.TileOrNull(tile) + off, 512 * sizeof(uint32_t));
    if (cs) std::memcpy(cs, counts.ColorTileOrNull(tile) + off, 512 * sizeof(uint64_t));
    return;
  }
  // Folded, only the z = 0 slice exists, scattered over a tile's rows.
  if (active) {
    for (int w = 0; w < 8; ++w)
      for (uint64_t bits = active[w]; bits; bits &= bits - 1) {
        const int i = w * 64 + std::countr_zero(bits);
        const uint64_t key = counts.Key(o.x + (i >> 6), o.y + ((i >> 3) & 7), o.z + (i & 7));
        const uint64_t tile = key >> 15, off = key & 0x7fff;
        v[i] = counts.TileOrNull(tile)[off];
        if (cs) cs[i] = counts.ColorTileOrNull(tile)[off];
      }
    return;
  }
  std::memset(v, 0, 512 * sizeof(uint32_t));
  if (cs) std::memset(cs, 0, 512 * sizeof(uint64_t));
  for (int i = 0; i < 8; ++i)
    for (int k = 0; k < 8; ++k) {
      const uint64_t key = counts.Key(o.x + i, o.y + k, 0);
      const uint64_t tile = key >> 15, off = key & 0x7fff;
      v[(i << 6) | (k << 3)] = counts.TileOrNull(tile)[off];
      if (cs) cs[(i << 6) | (k << 3)] = counts.ColorTileOrNull(tile)[off];
    }
}

}  // namespace nimbus
