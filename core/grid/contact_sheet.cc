#include "core/grid/contact_sheet.h"

#include <algorithm>
#include <cmath>
#include <string>

#include "absl/strings/str_cat.h"

namespace nimbus {

namespace {

// A 3 x 5 pixel font for the digits: one row of 3 bits per entry, top first.
constexpr unsigned char kDigits[10][5] = {
    {7, 5, 5, 5, 7}, {2, 6, 2, 2, 7}, {7, 1, 7, 4, 7}, {7, 1, 7, 1, 7}, {5, 5, 7, 1, 1},
    {7, 4, 7, 1, 7}, {7, 4, 7, 5, 7}, {7, 1, 1, 1, 1}, {7, 5, 7, 5, 7}, {7, 5, 7, 1, 7}};

void Fill(RgbImage& im, int x0, int y0, int w, int h, Vec3 c) {
  for (int y = std::max(y0, 0); y < std::min(y0 + h, im.height); ++y)
    for (int x = std::max(x0, 0); x < std::min(x0 + w, im.width); ++x) {
      float* p = im.At(x, y);
      p[0] = float(c.x), p[1] = float(c.y), p[2] = float(c.z);
    }
}

// White digits of `text` on a dark box at (x0, y0), `s` pixels per font
// pixel: readable on any thumbnail.
void DrawLabel(RgbImage& im, int x0, int y0, const std::string& text, int s) {
  const int w = int(text.size()) * 4 * s + s, h = 7 * s;
  Fill(im, x0, y0, w, h, {0, 0, 0});
  for (size_t k = 0; k < text.size(); ++k) {
    const int d = text[k] - '0';
    for (int row = 0; row < 5; ++row)
      for (int col = 0; col < 3; ++col)
        if (kDigits[d][row] & (4 >> col))
          Fill(im, x0 + s + int(k) * 4 * s + col * s, y0 + s + row * s, s, s, {1, 1, 1});
  }
}

}  // namespace

SheetLayout ContactSheetLayout(int count, int cell, int columns) {
  SheetLayout l;
  l.count = std::max(count, 1);
  l.cell = std::max(cell, 1);
  l.columns = columns > 0 ? columns : int(std::ceil(std::sqrt(double(l.count)) - 1e-9));
  l.columns = std::clamp(l.columns, 1, l.count);
  l.rows = (l.count + l.columns - 1) / l.columns;
  l.gap = std::max(2, l.cell / 32);
  return l;
}

absl::StatusOr<RgbImage> ComposeContactSheet(const std::vector<RgbImage>& thumbnails,
                                             const SheetLayout& layout, Vec3 background,
                                             bool labels) {
  if (int(thumbnails.size()) > layout.columns * layout.rows)
    return absl::InvalidArgumentError(absl::StrCat(thumbnails.size(), " thumbnails for ",
                                                   layout.columns * layout.rows, " cells"));
  RgbImage sheet;
  sheet.width = layout.width();
  sheet.height = layout.height();
  sheet.rgb.assign(size_t(sheet.width) * size_t(sheet.height) * 3, 0.f);
  Fill(sheet, 0, 0, sheet.width, sheet.height, background);
  // Font pixels of about a 40th of the cell, at least one.
  const int s = std::max(1, layout.cell / 40);
  for (size_t i = 0; i < thumbnails.size(); ++i) {
    const RgbImage& t = thumbnails[i];
    if (t.width != layout.cell || t.height != layout.cell)
      return absl::InvalidArgumentError(absl::StrCat("thumbnail ", i, " is ", t.width, " x ",
                                                     t.height, ", not ", layout.cell));
    const int x0 = layout.CellX(int(i)), y0 = layout.CellY(int(i));
    for (int y = 0; y < t.height; ++y)
      std::copy_n(t.At(0, y), size_t(t.width) * 3, sheet.At(x0, y0 + y));
    if (labels) DrawLabel(sheet, x0, y0, std::to_string(i + 1), s);
  }
  return sheet;
}

}  // namespace nimbus
