// @brief The image a chaos game can count into instead of a voxel grid:
// the projection from world space to pixels, and the layout of the pixel
// counters inside a CountGrid.
#pragma once

#include <cstdint>

#include "core/base/geometry.h"
#include "core/grid/image_look.h"

namespace nimbus {

/// @brief Pixels of a (supersampled) image and how world points reach them
/// (docs/images.md). Orthographic: `view` takes a world point straight to
/// (column, row, depth) with depth in [0, 1) inside the clip range.
/// Perspective: `view` gives camera coordinates (right, up, forward) and
/// the pixel is (cx + focal x / z, cy - focal y / z), for z > near.
/// The counters live in a CountGrid in the folded layout of
/// FoldedImageResolution (core/grid/image_look.h).
struct ImagePlane {
  int width = 0, height = 0;  // pixels, supersampling included
  Affine3 view;
  bool perspective = false;
  double focal = 0, cx = 0, cy = 0, near = 0;

  static constexpr int kFoldShift = kImageFoldShift;
  static constexpr uint32_t kFoldMask = kImageFoldMask;

  /// The CountGrid resolution holding the image (FoldedImageResolution).
  Int3 folded_resolution() const { return FoldedImageResolution(width, height); }
  static Int3 Voxel(int column, int row) { return FoldedImageVoxel(column, row); }

  /// Continuous pixel coordinates of `q`; false when it is not in view
  /// (outside the image, the depth clip, or behind the camera; NaN too).
  bool Project(Vec3 q, double* fx, double* fy) const {
    const Vec3 c = view.Apply(q);
    double x = c.x, y = c.y;
    if (perspective) {
      if (!(c.z > near)) return false;
      x = cx + focal * c.x / c.z;
      y = cy - focal * c.y / c.z;
    } else if (!(c.z >= 0 && c.z < 1)) {
      return false;
    }
    *fx = x, *fy = y;
    return x >= 0 && x < width && y >= 0 && y < height;
  }
};

/// @brief A picture's projection as the spec gives it: an axis framing
/// the grid box, or a camera.
struct ImageView {
  enum class Axis { kX, kY, kZ };
  Axis axis = Axis::kZ;
  bool camera = false;
  bool perspective = false;
  Vec3 position, look_at, up{0, 1, 0};
  double fov_degrees = 40;   // perspective, vertical
  double ortho_height = 0;   // orthographic camera; 0: fit the box
};

/// The height that keeps the framed box's aspect (axis views) or a square
/// picture (cameras), for `width` pixels; at least 1.
int DefaultImageHeight(const ImageView& view, const Bounds& box, int width);

/// The plane of a width x height picture (supersampling included) of
/// `box`: axis views and orthographic cameras fit the box (or
/// ortho_height) into the picture with square pixels and clip depth to the
/// box; perspective cameras clip only behind the eye.
ImagePlane MakeImagePlane(const ImageView& view, const Bounds& box, int width, int height);

/// The inverse of an affine map whose linear part is invertible.
Affine3 Inverse(const Affine3& a);

}  // namespace nimbus
