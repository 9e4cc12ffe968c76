// @brief A contact sheet: equal square thumbnails on a grid with gaps,
// each labelled with its 1-based index (docs/explore.md#the-contact-sheet).
#pragma once

#include <vector>

#include "absl/status/statusor.h"
#include "core/base/geometry.h"
#include "core/grid/image_look.h"

namespace nimbus {

/// @brief Where the cells of a contact sheet lie: `columns` x `rows` cells
/// of `cell` pixels, `gap` pixels between them and around the border, in
/// row-major order from the top left.
struct SheetLayout {
  int count = 0, columns = 1, rows = 1, cell = 1, gap = 0;
  int width() const { return columns * cell + (columns + 1) * gap; }
  int height() const { return rows * cell + (rows + 1) * gap; }
  /// Top-left pixel of cell `i` (0-based).
  int CellX(int i) const { return gap + (i % columns) * (cell + gap); }
  int CellY(int i) const { return gap + (i / columns) * (cell + gap); }
};

/// The layout of `count` cells of `cell` pixels: `columns` columns (0: the
/// smallest that makes the sheet at least as tall as wide in cells, i.e.
/// ceil(sqrt(count))), at most `count`; gap = max(2, cell / 32).
SheetLayout ContactSheetLayout(int count, int cell, int columns);

/// Draws `thumbnails` (each cell x cell) into their cells on `background`,
/// with the index of each in its top-left corner when `labels`.
absl::StatusOr<RgbImage> ComposeContactSheet(const std::vector<RgbImage>& thumbnails,
                                             const SheetLayout& layout, Vec3 background,
                                             bool labels);

}  // namespace nimbus
