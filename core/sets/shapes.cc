#include "core/sets/shapes.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include "absl/strings/str_cat.h"
#include "core/base/random.h"
#include "core/base/status_macros.h"

namespace nimbus {
namespace {

// Voxel index range [lo, hi] along `axis` whose centres lie in [a, b].
void CentreRange(const GridFrame& f, int axis, double a, double b, int& lo, int& hi) {
  const double h = f.VoxelSize()[axis], m = f.bounds.min[axis];
  lo = std::max(0, int(std::ceil((a - m) / h - 0.5)));
  hi = std::min(f.resolution[axis] - 1, int(std::floor((b - m) / h - 0.5)));
}

double Centre(const GridFrame& f, int axis, int i) {
  return f.bounds.min[axis] + (i + 0.5) * f.VoxelSize()[axis];
}

absl::Status CheckRadius(double r, const char* what) {
  if (!std::isfinite(r) || r < 0)
    return absl::InvalidArgumentError(absl::StrCat(what, " must be finite and >= 0"));
  return absl::OkStatus();
}

// Adds a ball to `set` (spans per row, so the cost follows the ball size).
void AddBall(const GridFrame& f, Vec3 c, double r, VoxelSet& set) {
  int z0, z1, y0, y1;
  CentreRange(f, 2, c.z - r, c.z + r, z0, z1);
  CentreRange(f, 1, c.y - r, c.y + r, y0, y1);
  for (int z = z0; z <= z1; ++z) {
    const double dz = Centre(f, 2, z) - c.z;
    for (int y = y0; y <= y1; ++y) {
      const double dy = Centre(f, 1, y) - c.y;
      const double s2 = r * r - dy * dy - dz * dz;
      if (s2 < 0) continue;
      const double s = std::sqrt(s2);
      int x0, x1;
      CentreRange(f, 0, c.x - s, c.x + s, x0, x1);
      set.SetSpan(x0, x1, y, z);
    }
  }
}

}  // namespace

absl::StatusOr<VoxelSet> SphereSet(const GridFrame& frame, Vec3 centre, double radius) {
  NIMBUS_RETURN_IF_ERROR(ValidateSetFrame(frame));
  NIMBUS_RETURN_IF_ERROR(CheckRadius(radius, "sphere radius"));
  if (!IsFinite(centre)) return absl::InvalidArgumentError("sphere centre must be finite");
  VoxelSet set(frame.resolution);
  AddBall(frame, centre, radius, set);
  return set;
}

absl::StatusOr<VoxelSet> BoxSet(const GridFrame& frame, const Bounds& box) {
  NIMBUS_RETURN_IF_ERROR(ValidateSetFrame(frame));
  if (!IsFinite(box.min) || !IsFinite(box.max))
    return absl::InvalidArgumentError("box corners must be finite");
  VoxelSet set(frame.resolution);
  int x0, x1, y0, y1, z0, z1;
  CentreRange(frame, 0, box.min.x, box.max.x, x0, x1);
  CentreRange(frame, 1, box.min.y, box.max.y, y0, y1);
  CentreRange(frame, 2, box.min.z, box.max.z, z0, z1);
  for (int z = z0; z <= z1; ++z)
    for (int y = y0; y <= y1; ++y) set.SetSpan(x0, x1, y, z);
  return set;
}

absl::StatusOr<VoxelSet> TorusSet(const GridFrame& frame, Vec3 centre, Vec3 axis,
                                  double major_radius, double minor_radius) {
  NIMBUS_RETURN_IF_ERROR(ValidateSetFrame(frame));
  NIMBUS_RETURN_IF_ERROR(CheckRadius(major_radius, "torus major radius"));
  NIMBUS_RETURN_IF_ERROR(CheckRadius(minor_radius, "torus minor radius"));
  const double len = Length(axis);
  if (!IsFinite(centre) || !IsFinite(axis) || !(len > 0))
    return absl::InvalidArgumentError("torus centre and axis must be finite, axis non-zero");
  const Vec3 n = (1.0 / len) * axis;
  const double reach = major_radius + minor_radius;
  VoxelSet set(frame.resolution);
  int x0, x1, y0, y1, z0, z1;
  CentreRange(frame, 0, centre.x - reach, centre.x + reach, x0, x1);
  CentreRange(frame, 1, centre.y - reach, centre.y + reach, y0, y1);
  CentreRange(frame, 2, centre.z - reach, centre.z + reach, z0, z1);
  for (int z = z0; z <= z1; ++z)
    for (int y = y0; y <= y1; ++y)
      for (int x = x0; x <= x1; ++x) {
        const Vec3 d = frame.VoxelCenter({x, y, z}) - centre;
        const double along = Dot(d, n);
        const double radial = Length(d - along * n) - major_radius;
        if (radial * radial + along * along <= minor_radius * minor_radius) set.Set(x, y, z);
      }
  return set;
}

absl::StatusOr<VoxelSet> RandomBallsInside(const VoxelSet& region, const GridFrame& frame,
                                           const RandomBallsOptions& options) {
  NIMBUS_RETURN_IF_ERROR(ValidateSetFrame(frame));
  if (!(region.resolution() == frame.resolution))
    return absl::InvalidArgumentError("random balls: region resolution differs from the frame");
  if (options.count < 0) return absl::InvalidArgumentError("random balls: count must be >= 0");
  NIMBUS_RETURN_IF_ERROR(CheckRadius(options.min_radius, "random balls min_radius"));
  NIMBUS_RETURN_IF_ERROR(CheckRadius(options.max_radius, "random balls max_radius"));
  if (options.max_radius < options.min_radius)
    return absl::InvalidArgumentError("random balls: max_radius < min_radius");
  // Members per row, accumulated, to pick the k-th member by binary search.
  const Int3 r = region.resolution();
  std::vector<int64_t> prefix(size_t(r.y) * r.z + 1, 0);
  for (int z = 0; z < r.z; ++z)
    for (int y = 0; y < r.y; ++y) {
      int64_t n = 0;
      const uint64_t* row = region.Row(y, z);
      for (int w = 0; w < region.words_per_row(); ++w) n += std::popcount(row[w]);
      const size_t i = size_t(z) * r.y + y;
      prefix[i + 1] = prefix[i] + n;
    }
  const int64_t members = prefix.back();
  if (members == 0) return absl::InvalidArgumentError("random balls: the region is empty");
  VoxelSet balls(frame.resolution);
  Rng rng(options.seed, 0x62616c6c73ULL);  // "balls"
  const Vec3 h = frame.VoxelSize();
  for (int b = 0; b < options.count; ++b) {
    const int64_t k = int64_t(rng.Uniform() * double(members));
    const size_t row =
        size_t(std::upper_bound(prefix.begin(), prefix.end(), k) - prefix.begin()) - 1;
    const int y = int(row % r.y), z = int(row / r.y);
    int64_t skip = k - prefix[row];
    int x = -1;
    const uint64_t* bits = region.Row(y, z);
    for (int w = 0; w < region.words_per_row() && x < 0; ++w) {
      const int n = std::popcount(bits[w]);
      if (skip >= n) {
        skip -= n;
        continue;
      }
      uint64_t word = bits[w];
      for (int64_t s = 0; s < skip; ++s) word &= word - 1;
      x = (w << 6) + std::countr_zero(word);
    }
    const Vec3 corner = frame.VoxelCenter({x, y, z}) - 0.5 * h;
    const Vec3 centre{corner.x + rng.Uniform() * h.x, corner.y + rng.Uniform() * h.y,
                      corner.z + rng.Uniform() * h.z};
    const double radius = rng.Uniform(options.min_radius, options.max_radius);
    AddBall(frame, centre, radius, balls);
  }
  if (options.clip_to_region) balls &= region;
  return balls;
}

}  // namespace nimbus
