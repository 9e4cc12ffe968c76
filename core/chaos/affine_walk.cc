#include "core/chaos/affine_walk.h"

namespace nimbus::walk {

namespace {

inline uint64_t Rotl(uint64_t x, int k) { return (x << k) | (x >> (64 - k)); }

// One step of one lane. The AVX2 kernel performs exactly these operations
// in the same order (no fused multiply-add), so both give the same bits.
template <bool kChain>
inline void Step(const AffineWalk& k, Walkers& w, int l) {
  uint64_t s0 = w.s0[l], s1 = w.s1[l], s2 = w.s2[l], s3 = w.s3[l];
  const uint64_t r = Rotl(s0 + s3, 23) + s0;
  const uint64_t t = s1 << 17;
  s2 ^= s0;
  s3 ^= s1;
  s1 ^= s2;
  s0 ^= s3;
  s2 ^= t;
  s3 = Rotl(s3, 45);
  w.s0[l] = s0, w.s1[l] = s1, w.s2[l] = s2, w.s3[l] = s3;

  uint32_t m;
  bool plotted = true;
  if constexpr (kChain) {
    const ChainTables& c = *k.chain;
    const uint64_t info = c.state[w.state[l]];
    const uint32_t off = uint32_t(info);
    const uint32_t i = uint32_t(((r >> 32) * (info >> 32)) >> 32);
    const uint64_t sample = c.sample[off + i];
    const uint32_t t = off + (uint32_t(r) < uint32_t(sample) ? i : uint32_t(sample >> 32));
    const uint64_t step = c.step[t];
    m = uint32_t(step) & 0x7fffffff;
    plotted = (step >> 31) & 1;
    w.state[l] = step >> 32;
  } else {
    const uint32_t i = uint32_t(((r >> 32) * k.num_maps) >> 32);
    m = uint32_t(r) < k.threshold[i] ? i : k.alias[i];
  }
  const double* c = k.coef + 12 * uint64_t(m);
  const double x = w.x[l], y = w.y[l], z = w.z[l];
  const double nx = c[0] * x + c[1] * y + c[2] * z + c[3];
  const double ny = c[4] * x + c[5] * y + c[6] * z + c[7];
  const double nz = c[8] * x + c[9] * y + c[10] * z + c[11];
  w.x[l] = nx, w.y[l] = ny, w.z[l] = nz;
  if (!plotted) {
    // x - x is 0 exactly when x is finite.
    if (!(nx - nx == 0 && ny - ny == 0 && nz - nz == 0)) [[unlikely]]
      k.exit(k.owner, l);
    return;
  }

  const double fx = (nx - k.min[0]) * k.inv_voxel[0];
  const double fy = (ny - k.min[1]) * k.inv_voxel[1];
  const double fz = (nz - k.min[2]) * k.inv_voxel[2];
  // Written so that NaN fails.
  if (!(fx >= 0 && fx < k.res[0] && fy >= 0 && fy < k.res[1] && fz >= 0 && fz < k.res[2]))
      [[unlikely]] {
    k.exit(k.owner, l);
    return;
  }
  const uint32_t ix = uint32_t(int(fx)), iy0 = uint32_t(int(fy)), iz0 = uint32_t(int(fz));
  if (k.flat) {
    ++k.flat[(ix * k.flat_stride[0] + iy0) * k.flat_stride[1] + iz0];
    return;
  }
  const uint32_t iy = iy0 >> k.fold_shift, iz = iz0 + (iy0 & k.fold_mask);
  const uint32_t tile = ((ix >> 5) * k.tiles_y + (iy >> 5)) * k.tiles_z + (iz >> 5);
  const uint32_t leaf = (((ix >> 3) & 3) << 4) | (((iy >> 3) & 3) << 2) | ((iz >> 3) & 3);
  const uint32_t local = (leaf << 9) | ((ix & 7) << 6) | ((iy & 7) << 3) | (iz & 7);
  if (k.tiles) {
    uint32_t* counts = k.tiles[tile];
    if (!counts) [[unlikely]]
      counts = k.allocate(k.owner, tile);
    ++counts[local];
    return;
  }
  const uint32_t bin = tile >> k.bin_shift;
  const uint32_t entry = ((tile & ((1u << k.bin_shift) - 1)) << 15) | local;
  BinCursor& cur = k.bins[bin];
  if (cur.tail == cur.end) [[unlikely]]
    k.refill(k.owner, bin);
  *cur.tail++ = entry;
}

template <bool kChain>
void Walk(const AffineWalk& k, Walkers& w, uint64_t steps) {
  for (uint64_t s = 0; s < steps; ++s)
    for (int l = 0; l < kLanes; ++l) Step<kChain>(k, w, l);
}

}  // namespace

void WalkScalar(const AffineWalk& k, Walkers& w, uint64_t steps) {
  if (k.chain)
    Walk<true>(k, w, steps);
  else
    Walk<false>(k, w, steps);
}

void WalkLane(const AffineWalk& k, Walkers& w, int lane, uint64_t steps) {
  for (uint64_t s = 0; s < steps; ++s) {
    if (k.chain)
      Step<true>(k, w, lane);
    else
      Step<false>(k, w, lane);
  }
}

}  // namespace nimbus::walk
