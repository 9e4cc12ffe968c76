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
#include <vector>

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
  // Map(c) for the small counts that make up most voxels, where the
  // mapping calls the C library (log1p, sqrt, pow): a lookup, same floats.
  std::vector<float> small;
  Normaliser(const DensityOptions& o, uint32_t max_count)
      : mapping(o.mapping),
        max(std::max<double>(1, max_count)),
        inv_max(1.0 / max),
        inv_log_max(1.0 / std::log1p(max)),
        inv_gamma(1.0 / (o.gamma > 0 ? o.gamma : 1.0)) {
    constexpr uint32_t kSmall = 4096;
    if (mapping == DensityMapping::kLinear) return;
    small.resize(std::min(kSmall, max_count) + size_t{1});
    for (uint32_t c = 0; c < small.size(); ++c) small[c] = Map(c);
  }
  float operator()(uint32_t c) const { return c < small.size() ? small[c] : Map(c); }

 private:
  float Map(uint32_t c) const {
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

// What both writers of a result take from its counts, computed once: the
// largest and total count (recorded as metadata), the density's
// normaliser, and whether colour is written.
struct CountedResult {
  const CountGrid& counts;
  const DensityOptions& options;
  const Metadata& metadata;
  CountGrid::Sums sums;
  Normaliser norm;
  bool color;

  CountedResult(const CountGrid& c, const DensityOptions& o, const Metadata& m)
      : counts(c),
        options(o),
        metadata(m),
        sums(c.MaxAndTotal()),
        norm(o, sums.max),
        color(o.color && c.has_color()) {}
};

// The 512 counters (and colour sums, when `cs`) of the voxel leaf at `o`,
// in LeafNode order, as CountGrid::ForEachLeaf hands them out.
inline void GatherCountLeaf(const CountGrid& counts, Int3 o, uint32_t* v, uint64_t* cs) {
  if (!counts.folded()) {
    // Unfolded, a voxel leaf is 512 consecutive counters of one tile.
    const uint64_t key = counts.Key(o.x, o.y, o.z);
    const uint64_t tile = key >> 15, off = key & 0x7fff;
    std::memcpy(v, counts.TileOrNull(tile) + off, 512 * sizeof(uint32_t));
    if (cs) std::memcpy(cs, counts.ColorTileOrNull(tile) + off, 512 * sizeof(uint64_t));
    return;
  }
  // Folded, only the z = 0 slice exists, scattered over a tile's rows.
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

/// The counters (and colour sums, when `cs`) of the voxels of the leaf at
/// `o` that `active` marks, packed in voxel order, with each one's index in
/// the leaf in `at`; returns how many. The writers' inner loop: it finds
/// the leaf's stored block once rather than each voxel's key.
inline size_t GatherActiveCounts(const CountGrid& counts, Int3 o, const uint64_t* active,
                                 uint16_t* at, uint32_t* v, uint64_t* cs) {
  const uint64_t key = counts.Key(o.x, o.y, o.z);
  const uint64_t tile = key >> 15, off = key & 0x7fff;
  const uint32_t* t = counts.TileOrNull(tile) + off;
  const uint64_t* c = cs ? counts.ColorTileOrNull(tile) + off : nullptr;
  // Voxel i of the leaf lies at t[i] unfolded. Folded only z = 0 exists and
  // voxel (a, b, 0), i = a << 6 | b << 3, lies at t[a << 6 | b].
  const int shift = counts.folded() ? 3 : 0;
  size_t n = 0;
  for (int w = 0; w < 8; ++w)
    for (uint64_t bits = active[w]; bits; bits &= bits - 1) {
      const int i = w * 64 + std::countr_zero(bits);
      const int s = (w << 6) | ((i & 63) >> shift);
      at[n] = uint16_t(i);
      v[n] = t[s];
      if (c) cs[n] = c[s];
      ++n;
    }
  return n;
}

}  // namespace nimbus
