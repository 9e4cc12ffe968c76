#include "tests/support/plot_oracle.h"

#include <algorithm>

namespace nimbus::testing {

std::optional<uint64_t> ExpectedPlotKey(const ChaosGameParams& p, const CountGrid& grid, Vec3 q,
                                        double col) {
  uint64_t color = 0;
  if (p.color.mode != ColorMode::kNone) {
    const double c = std::clamp(col, 0.0, 1.0);
    color = CountGrid::WithColor(0, uint32_t(c * CountGrid::kColorScale + 0.5));
  }
  if (p.image) {
    double fx = 0, fy = 0;
    if (!p.image->Project(q, &fx, &fy)) return std::nullopt;
    const Int3 v = ImagePlane::Voxel(int(fx), int(fy));
    return grid.Key(v.x, v.y, v.z) | color;
  }
  const Vec3 size = p.frame.VoxelSize();
  const Vec3 f{(q.x - p.frame.bounds.min.x) * (1.0 / size.x),
               (q.y - p.frame.bounds.min.y) * (1.0 / size.y),
               (q.z - p.frame.bounds.min.z) * (1.0 / size.z)};
  const Int3 r = p.frame.resolution;
  for (int a = 0; a < 3; ++a)
    if (!(f[a] >= 0 && f[a] < r[a])) return std::nullopt;
  return grid.Key(int(f.x), int(f.y), int(f.z)) | color;
}

}  // namespace nimbus::testing
