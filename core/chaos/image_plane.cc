#include "core/chaos/image_plane.h"

#include <algorithm>
#include <cmath>
#include <numbers>

namespace nimbus {

Affine3 Inverse(const Affine3& a) {
  const auto& m = a.m;
  // The adjugate of the linear part over its determinant.
  const double det = a.Determinant();
  Affine3 r;
  r.m[0] = {m[1][1] * m[2][2] - m[1][2] * m[2][1], m[0][2] * m[2][1] - m[0][1] * m[2][2],
            m[0][1] * m[1][2] - m[0][2] * m[1][1], 0};
  r.m[1] = {m[1][2] * m[2][0] - m[1][0] * m[2][2], m[0][0] * m[2][2] - m[0][2] * m[2][0],
            m[0][2] * m[1][0] - m[0][0] * m[1][2], 0};
  r.m[2] = {m[1][0] * m[2][1] - m[1][1] * m[2][0], m[0][1] * m[2][0] - m[0][0] * m[2][1],
            m[0][0] * m[1][1] - m[0][1] * m[1][0], 0};
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) r.m[i][j] /= det;
  const Vec3 t = r.ApplyLinear(a.translation());
  for (int i = 0; i < 3; ++i) r.m[i][3] = -t[i];
  return r;
}

namespace {

// World-to-view rows (right, up, forward) of a view and its eye.
struct Basis {
  Vec3 right, up, forward;
};

Vec3 Normalize(Vec3 v) { return (1.0 / Length(v)) * v; }

Basis AxisBasis(ImageView::Axis axis) {
  switch (axis) {
    case ImageView::Axis::kX: return {{0, 0, -1}, {0, 1, 0}, {-1, 0, 0}};
    case ImageView::Axis::kY: return {{1, 0, 0}, {0, 0, -1}, {0, -1, 0}};
    case ImageView::Axis::kZ: break;
  }
  return {{1, 0, 0}, {0, 1, 0}, {0, 0, -1}};
}

Basis ViewBasis(const ImageView& v) {
  if (!v.camera) return AxisBasis(v.axis);
  const Vec3 f = Normalize(v.look_at - v.position);
  const Vec3 r = Normalize(Cross(f, v.up));
  return {r, Cross(r, f), f};
}

// Range of Dot(d, corner) over the box's eight corners.
void Extent(const Bounds& box, Vec3 d, double* lo, double* hi) {
  *lo = 1e300, *hi = -1e300;
  for (int c = 0; c < 8; ++c) {
    const Vec3 p{(c & 1) ? box.max.x : box.min.x, (c & 2) ? box.max.y : box.min.y,
                 (c & 4) ? box.max.z : box.min.z};
    *lo = std::min(*lo, Dot(d, p));
    *hi = std::max(*hi, Dot(d, p));
  }
}

}  // namespace

int DefaultImageHeight(const ImageView& view, const Bounds& box, int width) {
  if (view.camera) return width;
  const Basis b = ViewBasis(view);
  double x0, x1, y0, y1;
  Extent(box, b.right, &x0, &x1);
  Extent(box, b.up, &y0, &y1);
  const double h = std::round(double(width) * (y1 - y0) / (x1 - x0));
  return int(std::clamp(h, 1.0, 65536.0));
}

ImagePlane MakeImagePlane(const ImageView& view, const Bounds& box, int width, int height) {
  ImagePlane out;
  out.width = width;
  out.height = height;
  const Basis b = ViewBasis(view);
  if (view.perspective) {
    const Vec3 e = view.position;
    const Vec3 rows[3] = {b.right, b.up, b.forward};
    for (int r = 0; r < 3; ++r) out.view.m[r] = {rows[r].x, rows[r].y, rows[r].z, -Dot(rows[r], e)};
    out.perspective = true;
    out.focal = 0.5 * height / std::tan(0.5 * view.fov_degrees * std::numbers::pi / 180);
    out.cx = 0.5 * width;
    out.cy = 0.5 * height;
    out.near = 1e-9 * Length(box.Size());
    return out;
  }
  double x0, x1, y0, y1, z0, z1;
  Extent(box, b.right, &x0, &x1);
  Extent(box, b.up, &y0, &y1);
  const Vec3 back = -1.0 * b.forward;
  Extent(box, back, &z0, &z1);
  // The view's centre: the box centre, or the camera's line of sight.
  double cx = 0.5 * (x0 + x1), cy = 0.5 * (y0 + y1);
  double scale = std::min(width / (x1 - x0), height / (y1 - y0));
  if (view.camera) {
    cx = Dot(b.right, view.look_at), cy = Dot(b.up, view.look_at);
    if (view.ortho_height > 0) scale = height / view.ortho_height;
  }
  // Depth runs backwards along the view, so an axis view clips the world
  // coordinate to [min, max) exactly as the volume's voxels do; a flat box
  // gets a unit slab around it.
  const double dz = z1 > z0 ? z1 - z0 : 1;
  const double zmin = z1 > z0 ? z0 : z0 - 0.5;
  const Vec3 col = scale * b.right, row = -scale * b.up, depth = (1 / dz) * back;
  out.view.m[0] = {col.x, col.y, col.z, 0.5 * width - scale * cx};
  out.view.m[1] = {row.x, row.y, row.z, 0.5 * height + scale * cy};
  out.view.m[2] = {depth.x, depth.y, depth.z, -zmin / dz};
  return out;
}

}  // namespace nimbus
