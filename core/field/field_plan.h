// @brief A validated fractal-field job: the field, what to write (a density
// volume or a terrain), the frames of an animation and an optional shape
// the cloud takes (docs/fractal_fields.md).
#pragma once

#include <cstdint>
#include <optional>

#include "core/field/fractal_field.h"
#include "core/sets/set_source.h"

namespace nimbus {

enum class FieldOutputKind {
  kDensity,  // a 3D fog volume from a 3D (or, animated, 4D) field
  kTerrain,  // a height field from a 2D (or, animated, 3D) field
};

/// @brief v = field / WeightSum (in [-1, 1]), then y = gain (v - threshold);
/// density 0 for y <= 0, else min(y, 1), or 1 - e^-y with soft_clip.
struct FieldDensityOptions {
  double threshold = 0;
  double gain = 1;
  bool soft_clip = false;
};

/// @brief height = base_height + height_scale * v (world units, along z).
struct FieldTerrainOptions {
  double base_height = 0;
  double height_scale = 0.5;
  bool png = true;
};

/// @brief Frame f (0-based) is at time time_start + f' * time_step, where
/// f' = f, or f mod frames for a loop (then the field must repeat in time:
/// the converter gives the time axis the period frames * time_step and
/// checks the wind).
struct FieldAnimation {
  int64_t frames = 0;  // 0: one still result
  double time_start = 0;
  double time_step = 1;
  bool loop = false;
};

/// @brief A cloud shaped like `source`: v = -sdf / falloff + detail * v.
struct FieldShapePlan {
  SetSourcePlan source;
  double falloff = 0.1;  // world units
  double detail = 0.5;
};

struct FractalFieldPlan {
  FractalFieldParams field;
  FieldOutputKind output = FieldOutputKind::kDensity;
  FieldDensityOptions density;
  FieldTerrainOptions terrain;
  FieldAnimation animation;
  std::optional<FieldShapePlan> shape;
};

/// The time of frame `index` (loop frames wrap first, in integers, so frame
/// `frames` is frame 0 bit for bit).
double FrameTime(const FieldAnimation& animation, int64_t index);

}  // namespace nimbus
