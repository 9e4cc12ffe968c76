// @brief The look of a chaos-game picture: supersampled pixel counters
// box-filtered down, density tone mapping, address colour through a
// palette, desaturation and glow (docs/images.md).
#pragma once

#include <cstdint>
#include <vector>

#include "absl/status/statusor.h"
#include "core/base/geometry.h"
#include "core/base/interrupter.h"
#include "core/base/zero_pages.h"
#include "core/grid/count_grid.h"
#include "core/grid/palette.h"

namespace nimbus {

/// How visit density becomes intensity in [0, 1].
enum class ToneMapping {
  kSqrt,    // (sqrt d - sqrt dmin) / (sqrt dmax - sqrt dmin) over lit pixels
  kLog,     // log(1 + d) / log(1 + dmax)
  kGamma,   // (d / dmax)^(1 / gamma)
  kLinear,  // d / dmax
};

/// @brief Every parameter of the look, already validated by the spec
/// converter (ranges in docs/spec_reference.md).
struct LookParams {
  ToneMapping tone = ToneMapping::kSqrt;
  double gamma = 2.2;
  /// Colour the picture by the accumulated colour coordinate through
  /// `palette`; false: grey.
  bool colored = true;
  Palette palette;
  double desaturation = 0;  // in [0, 1]: 0 keeps the colour, 1 grey
  double glow = 0;          // in [0, 4]: weight of the blurred copy added back
  double glow_radius = 0;   // Gaussian sigma in output pixels
  double brightness = 1;    // intensity multiplier, > 0
  Vec3 background;          // colour of pixels no point reached
};

/// Pixel buffers: huge pages and no clearing from 1 MiB on
/// (ZeroPageAllocator); whoever fills one writes every element.
using PixelBuffer = std::vector<float, ZeroPageAllocator<float>>;

/// @brief Box-filtered pixel data: mean visits per sample and mean colour
/// coordinate of each output pixel (rows top first).
struct ImageDensity {
  int width = 0, height = 0;
  PixelBuffer density;  // visits per supersample
  PixelBuffer color;    // in [0, 1]; 0 where nothing landed
};

/// @brief Linear RGB floats, rows top first, 3 per pixel.
struct RgbImage {
  int width = 0, height = 0;
  PixelBuffer rgb;
  float* At(int x, int row) { return &rgb[3 * (size_t(row) * size_t(width) + size_t(x))]; }
  const float* At(int x, int row) const {
    return &rgb[3 * (size_t(row) * size_t(width) + size_t(x))];
  }
};

/// @brief The image layout inside a CountGrid: row r of a picture is voxel
/// (column, r >> 5, r & 31), so a 32^3 tile holds a block of 32 columns by
/// 1024 rows and no counter is wasted on a depth the picture lacks.
inline constexpr int kImageFoldShift = 5;
inline constexpr uint32_t kImageFoldMask = 31;
inline Int3 FoldedImageResolution(int width, int height) {
  return {width, (height + 31) >> kImageFoldShift, 32};
}
inline Int3 FoldedImageVoxel(int column, int row) {
  return {column, row >> kImageFoldShift, int(uint32_t(row) & kImageFoldMask)};
}

/// Sums each `factor` x `factor` block of samples of the folded image
/// counters `parts` (summed; each holds samples_w x samples_h samples) into
/// one output pixel of ceil(samples_w / factor) x ceil(samples_h / factor).
/// `taps` <= factor evenly spaced samples per axis are read (factor: the
/// exact box filter; fewer: a cheap preview). Partial blocks at the right
/// and bottom edges average the samples they have.
absl::StatusOr<ImageDensity> BoxFilterImage(const std::vector<const CountGrid*>& parts,
                                            int samples_w, int samples_h, int factor, int taps,
                                            Interrupter* interrupter);

/// Intensity in [0, 1] of density `d` given the lit pixels' smallest and
/// largest density (both > 0): monotone non-decreasing in d.
double ToneMap(const LookParams& look, double d, double dmin, double dmax);

/// @brief The look without its glow, a band of rows at a time, for
/// pictures encoded as they are developed. Every row depends on its own
/// pixels and on the picture's least and greatest lit density only.
///
///   Developer dev(density, look);  // finds those two densities
///   dev.Rows(first, last, rgb);    // from any thread
class Developer {
 public:
  /// Holds `image` and `look` by reference.
  Developer(const ImageDensity& image, const LookParams& look);
  /// Rows [first, last) into `rgb`, 3 floats per pixel, row after row.
  void Rows(int first, int last, float* rgb) const;

 private:
  void Row(int row, float* rgb) const;
  Vec3 Shade(Vec3 colour, double value) const;

  const ImageDensity& image_;
  const LookParams& look_;
  float dmin_ = 0, dmax_ = 0;
};

/// Applies tone mapping, palette, desaturation, brightness and glow.
absl::StatusOr<RgbImage> DevelopImage(const ImageDensity& image, const LookParams& look,
                                      Interrupter* interrupter);

/// Whether a glow of `amount` and `radius` changes the picture: only then
/// does developing it need the whole picture at once.
inline bool HasGlow(double amount, double radius) { return amount > 0 && radius > 0; }

/// Adds `amount` times a Gaussian blur (sigma `radius` pixels, as three
/// successive box filters per axis) of `image` to itself; amount 0 or
/// radius 0 leaves it unchanged.
void AddGlow(RgbImage& image, double amount, double radius);

}  // namespace nimbus
