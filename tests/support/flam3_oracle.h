// flam3-render (Debian's flam3-utils) as an oracle: renders a genome into a
// picture of grey levels, and compares two pictures by the correlation of
// their cell means. Used by the variation and import agreement tests.
#pragma once

#include <string>
#include <vector>

namespace nimbus::testing {

bool HaveFlam3();

/// Renders `genome` (flam3 XML with `width` x `height` pixels) with one
/// thread; returns the red channel, row 0 being the picture's top row
/// (which flam3 fills with the smallest y).
std::vector<double> RenderWithFlam3(const std::string& genome, const std::string& dir,
                                    const std::string& name, int width, int height);

/// Pearson correlation of the means of `cell` x `cell` blocks of two
/// pictures of the same size.
double CellCorrelation(const std::vector<double>& a, const std::vector<double>& b, int width,
                       int height, int cell);

}  // namespace nimbus::testing
