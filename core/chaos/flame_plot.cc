// The portable plot kernel, one walker at a time: the reference the SIMD
// kernels are tested against, and bitwise what ChaosGame's Plot computes
// for a point without arcs or splatting.
#include "core/chaos/flame_plot.h"

#include <cmath>

namespace nimbus::flame {
namespace {

bool Finite(double x, double y, double z) {
  return std::isfinite(x) && std::isfinite(y) && std::isfinite(z);
}

// CountGrid::Key of voxel (x, y, z) with the target's fold and tiles.
uint64_t KeyOf(const PlotTarget& t, int x, int y, int z) {
  const int sy = y >> t.fold_shift, sz = z + int(uint32_t(y) & t.fold_mask);
  const uint64_t tile =
      (uint64_t(x >> 5) * t.tiles_y + uint64_t(sy >> 5)) * t.tiles_z + uint64_t(sz >> 5);
  const int lx = x & 31, ly = sy & 31, lz = sz & 31;
  const uint32_t offset =
      (uint32_t(((lx >> 3) << 4) | ((ly >> 3) << 2) | (lz >> 3)) << 9) |
      uint32_t(((lx & 7) << 6) | ((ly & 7) << 3) | (lz & 7));
  return tile << 15 | offset;
}

// The point's continuous lattice coordinates; false when it misses the
// lattice (NaN included), as Plot and ImagePlane::Project decide.
bool Project(const PlotTarget& t, double x, double y, double z, double f[3]) {
  if (t.kind == PlotTarget::kGrid) {
    f[0] = (x - t.min[0]) * t.inv_voxel[0];
    f[1] = (y - t.min[1]) * t.inv_voxel[1];
    f[2] = (z - t.min[2]) * t.inv_voxel[2];
  } else {
    const double* v = t.view;
    double cx = v[0] * x + v[1] * y + v[2] * z + v[3];
    double cy = v[4] * x + v[5] * y + v[6] * z + v[7];
    const double cz = v[8] * x + v[9] * y + v[10] * z + v[11];
    if (t.kind == PlotTarget::kPerspective) {
      if (!(cz > t.near)) return false;
      cx = t.cx + t.focal * cx / cz;
      cy = t.cy - t.focal * cy / cz;
    } else if (!(cz >= 0 && cz < 1)) {
      return false;
    }
    f[0] = cx, f[1] = cy, f[2] = 0;
  }
  return f[0] >= 0 && f[0] < t.res[0] && f[1] >= 0 && f[1] < t.res[1] && f[2] >= 0 &&
         f[2] < t.res[2];
}

// ChaosGame's ColorBits: the clamped colour coordinate in 16 bits at 48.
uint64_t ColorBits(double col) {
  const double c = col < 0.0 ? 0.0 : 1.0 < col ? 1.0 : col;
  return uint64_t(uint32_t(c * 65535.0 + 0.5)) << 48;
}

}  // namespace

void PlotScalar(const PlotTarget& t, const Walkers& w, bool final_map, int n, Plotted* out) {
  const double* px = final_map ? w.fx : w.x;
  const double* py = final_map ? w.fy : w.y;
  const double* pz = final_map ? w.fz : w.z;
  out->ClearMasks();
  for (int k = 0; k < n; ++k) {
    const int word = k / 64;
    const uint64_t bit = uint64_t{1} << (k % 64);
    if (!Finite(w.x[k], w.y[k], w.z[k])) {
      out->bad_walker[word] |= bit;
      continue;
    }
    if (!Finite(px[k], py[k], pz[k])) {
      out->bad_final[word] |= bit;
      continue;
    }
    double f[3];
    if (!Project(t, px[k], py[k], pz[k], f)) continue;
    out->inside[word] |= bit;
    out->key[k] = KeyOf(t, int(f[0]), int(f[1]), int(f[2])) | (t.color ? ColorBits(w.col[k]) : 0);
  }
}

}  // namespace nimbus::flame
