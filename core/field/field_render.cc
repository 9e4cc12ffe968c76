#include "core/field/field_render.h"

#include <algorithm>
#include <cmath>

#include "absl/strings/str_cat.h"
#include "core/base/status_macros.h"
#include "core/sets/feature_transform.h"

namespace nimbus {

namespace {

double Normalized(double value, double weight_sum) {
  return weight_sum > 0 ? value / weight_sum : 0.0;
}

float DensityOf(double v, const FieldDensityOptions& o) {
  const double y = o.gain * (v - o.threshold);
  if (!(y > 0)) return 0.f;
  return float(o.soft_clip ? -std::expm1(-y) : std::min(y, 1.0));
}

}  // namespace

double FrameTime(const FieldAnimation& a, int64_t index) {
  if (a.loop && a.frames > 0) index = ((index % a.frames) + a.frames) % a.frames;
  return a.time_start + double(index) * a.time_step;
}

FieldGrid VoxelCentres(const GridFrame& frame, int space_dims, double t) {
  FieldGrid g;
  const Vec3 h = frame.VoxelSize();
  const int res[3] = {frame.resolution.x, frame.resolution.y, frame.resolution.z};
  for (int i = 0; i < space_dims; ++i) {
    g.count[size_t(i)] = res[i];
    g.step[size_t(i)] = h[i];
    g.origin[size_t(i)] = frame.bounds.min[i] + 0.5 * h[i];
  }
  g.time = t;
  return g;
}

absl::StatusOr<FloatVolume> RenderDensity(const FractalField& field, const FractalFieldPlan& plan,
                                          const GridFrame& frame, double t,
                                          const std::vector<float>* shape_sdf,
                                          Interrupter* interrupter) {
  FloatVolume vol;
  vol.frame = frame;
  vol.values.resize(size_t(frame.resolution.Volume()));
  NIMBUS_RETURN_IF_ERROR(
      EvaluateFieldGrid(field, VoxelCentres(frame, 3, t), vol.values.data(), interrupter));
  const double w = field.WeightSum();
  const bool shaped = plan.shape.has_value() && shape_sdf != nullptr;
  for (size_t i = 0; i < vol.values.size(); ++i) {
    double v = Normalized(vol.values[i], w);
    if (shaped) v = -double((*shape_sdf)[i]) / plan.shape->falloff + plan.shape->detail * v;
    vol.values[i] = DensityOf(v, plan.density);
  }
  return vol;
}

absl::StatusOr<HeightField> RenderHeights(const FractalField& field, const FractalFieldPlan& plan,
                                          const GridFrame& frame, double t,
                                          Interrupter* interrupter) {
  HeightField h;
  h.nx = frame.resolution.x;
  h.ny = frame.resolution.y;
  h.normalized.resize(size_t(h.nx) * size_t(h.ny));
  NIMBUS_RETURN_IF_ERROR(
      EvaluateFieldGrid(field, VoxelCentres(frame, 2, t), h.normalized.data(), interrupter));
  h.heights.resize(h.normalized.size());
  const double w = field.WeightSum();
  for (size_t i = 0; i < h.normalized.size(); ++i) {
    const double v = Normalized(h.normalized[i], w);
    h.normalized[i] = float(v);
    h.heights[i] = float(plan.terrain.base_height + plan.terrain.height_scale * v);
  }
  return h;
}

FloatVolume TerrainLevelSet(const HeightField& h, const GridFrame& frame) {
  FloatVolume vol;
  vol.frame = frame;
  vol.grid_name = "surface";
  vol.level_set = true;
  const Vec3 s = frame.VoxelSize();
  vol.background = float(3 * std::max({s.x, s.y, s.z}));
  const int nz = frame.resolution.z;
  vol.values.assign(size_t(frame.resolution.Volume()), vol.background);
  auto height = [&](int x, int y) {
    x = std::clamp(x, 0, h.nx - 1);
    y = std::clamp(y, 0, h.ny - 1);
    return double(h.heights[size_t(x) * size_t(h.ny) + size_t(y)]);
  };
  for (int x = 0; x < h.nx; ++x)
    for (int y = 0; y < h.ny; ++y) {
      // First-order distance to the surface: the vertical gap over the
      // slope's secant.
      const double gx = (height(x + 1, y) - height(x - 1, y)) / (2 * s.x);
      const double gy = (height(x, y + 1) - height(x, y - 1)) / (2 * s.y);
      const double inv = 1 / std::sqrt(1 + gx * gx + gy * gy);
      const double hz = height(x, y);
      float* col = &vol.values[(size_t(x) * size_t(h.ny) + size_t(y)) * size_t(nz)];
      for (int z = 0; z < nz; ++z) {
        const double d = (frame.bounds.min.z + (z + 0.5) * s.z - hz) * inv;
        col[z] = float(std::clamp(d, -double(vol.background), double(vol.background)));
      }
    }
  return vol;
}

Gray16Image HeightMap16(const HeightField& h) {
  Gray16Image img;
  img.width = h.nx;
  img.height = h.ny;
  img.pixels.resize(size_t(h.nx) * size_t(h.ny));
  for (int x = 0; x < h.nx; ++x)
    for (int y = 0; y < h.ny; ++y) {
      const double v = std::clamp((double(h.normalized[size_t(x) * size_t(h.ny) + size_t(y)]) + 1) / 2,
                                  0.0, 1.0);
      img.pixels[size_t(h.ny - 1 - y) * size_t(h.nx) + size_t(x)] =
          uint16_t(std::lround(v * 65535));
    }
  return img;
}

absl::StatusOr<std::vector<float>> ShapeSignedDistance(const SetSourcePlan& source,
                                                       const GridFrame& frame,
                                                       Interrupter* interrupter) {
  NIMBUS_ASSIGN_OR_RETURN(VoxelSet inside, BuildSetSource(source, frame, nullptr, interrupter));
  VoxelSet outside(frame.resolution);
  outside.Fill();
  outside -= inside;
  const Vec3 h = frame.VoxelSize();
  NIMBUS_ASSIGN_OR_RETURN(FeatureField to_inside, ComputeFeatureTransform(inside, h, interrupter));
  NIMBUS_ASSIGN_OR_RETURN(FeatureField to_outside,
                          ComputeFeatureTransform(outside, h, interrupter));
  const Int3 r = frame.resolution;
  std::vector<float> sdf(size_t(r.Volume()));
  // Far from everything (an empty shape): a distance beyond any falloff.
  const double far = Length(frame.bounds.Size());
  for (int x = 0; x < r.x; ++x)
    for (int y = 0; y < r.y; ++y)
      for (int z = 0; z < r.z; ++z) {
        const bool in = inside.Get(x, y, z);
        const PackedVoxel n = in ? to_outside.At(x, y, z) : to_inside.At(x, y, z);
        // Voxel centres: half a voxel from the boundary on either side.
        const double d = n == kNoVoxel ? far
                                       : std::sqrt(SquaredDistance({x, y, z}, UnpackVoxel(n), h)) -
                                             0.5 * std::min({h.x, h.y, h.z});
        sdf[(size_t(x) * size_t(r.y) + size_t(y)) * size_t(r.z) + size_t(z)] =
            float(in ? -d : d);
      }
  return sdf;
}

}  // namespace nimbus
