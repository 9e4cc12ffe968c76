// @brief 16-bit greyscale PNG files, for height maps: written by
// png_encoder.h, read with libpng, which stays behind this header.
#pragma once

#include <cstdint>
#include <filesystem>
#include <vector>

#include "absl/status/statusor.h"

namespace nimbus {

/// @brief A greyscale image, rows top first.
struct Gray16Image {
  int width = 0, height = 0;
  std::vector<uint16_t> pixels;  // width * height, row-major

  uint16_t At(int x, int row) const { return pixels[size_t(row) * size_t(width) + size_t(x)]; }
};

/// Writes `image` as a 16-bit greyscale PNG through a temporary file
/// renamed into place. No timestamps or text chunks: the same image gives
/// the same bytes.
absl::Status WritePng16(const std::filesystem::path& path, const Gray16Image& image);

/// Reads a 16-bit greyscale PNG written by WritePng16 (tests, tools).
absl::StatusOr<Gray16Image> ReadPng16(const std::filesystem::path& path);

}  // namespace nimbus
