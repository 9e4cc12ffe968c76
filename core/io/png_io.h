// @brief PNG files through libpng, which stays behind this header: the one
// writer of every picture, contact sheet and height map, and a reader for
// 16-bit greyscale height maps.
//
//   PngShape shape{width, height, 8, 3};
//   NIMBUS_RETURN_IF_ERROR(WritePngFile(path, shape, [&](int first, int last, uint8_t* out) {
//     ...  // rows [first, last) of host-order samples
//     return absl::OkStatus();
//   }, interrupter));
#pragma once

#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "core/base/interrupter.h"

namespace nimbus {

/// @brief A picture's sample layout: `channels` 1 (grey) or 3 (RGB) per
/// pixel, `depth` 8 or 16 bits per sample.
struct PngShape {
  int width = 0, height = 0, depth = 8, channels = 3;
  size_t RowBytes() const { return size_t(width) * size_t(channels) * size_t(depth / 8); }
};

/// Where the PNG goes: an open file, or else a growing string.
struct PngSink {
  FILE* file = nullptr;
  std::string* bytes = nullptr;
};

/// Writes rows [first, last) of host-order samples, `RowBytes()` each and
/// one after another, into `out`. Called from several threads at once for
/// disjoint bands of rows.
using PngRows = std::function<absl::Status(int first, int last, uint8_t* out)>;

/// @brief Encodes the picture `rows` makes with libpng at its default
/// settings (a filter chosen per row, zlib level 6), with no timestamps or
/// text chunks: the same rows give the same bytes. Bands of rows are made
/// in parallel ahead of libpng, which filters and deflates them in order on
/// the calling thread. Errors: a bad shape, a failing `rows` or sink (a
/// full disk is RESOURCE_EXHAUSTED "disk full while writing the result"),
/// or CANCELLED when `interrupter` asks.
absl::Status WritePng(const PngShape& shape, const PngRows& rows, const PngSink& sink,
                      Interrupter* interrupter = nullptr);

/// WritePng into `path` through `path`.partial, renamed into place when
/// whole and removed otherwise; errors name the file, never its folder.
absl::Status WritePngFile(const std::filesystem::path& path, const PngShape& shape,
                          const PngRows& rows, Interrupter* interrupter = nullptr);

/// @brief A greyscale image, rows top first.
struct Gray16Image {
  int width = 0, height = 0;
  std::vector<uint16_t> pixels;  // width * height, row-major

  uint16_t At(int x, int row) const { return pixels[size_t(row) * size_t(width) + size_t(x)]; }
};

/// Writes `image` as a 16-bit greyscale PNG (WritePngFile).
absl::Status WritePng16(const std::filesystem::path& path, const Gray16Image& image);

/// Reads a 16-bit greyscale PNG written by WritePng16 (tests, tools).
absl::StatusOr<Gray16Image> ReadPng16(const std::filesystem::path& path);

}  // namespace nimbus
