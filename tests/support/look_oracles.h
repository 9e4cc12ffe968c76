// Independent references for the picture look (docs/images.md): the
// discrete kernel of a cascade of box filters, convolved out term by term,
// and the lit fraction of a developed picture counted from its pixels.
#pragma once

#include <vector>

#include "core/base/geometry.h"
#include "core/grid/image_look.h"

namespace nimbus::testing {

/// The 1D kernel of box filters of the given odd widths applied in turn,
/// by direct convolution: 1 + Σ (w - 1) taps, centred, summing to 1.
std::vector<double> BoxCascadeKernel(const std::vector<int>& widths);

/// The fraction of pixels of `image` whose RGB differs from `background`
/// (a colour no lit pixel can take, e.g. a negative one).
double LitFraction(const RgbImage& image, Vec3 background);

}  // namespace nimbus::testing
