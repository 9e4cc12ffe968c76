// @brief A PNG encoder that makes and filters its rows in parallel bands
// while one thread deflates them in order, writing byte for byte the file
// libpng 1.6 writes with its default settings (docs/images.md, "PNG bytes").
//
//   PngShape shape{width, height, 8, 3};
//   NIMBUS_RETURN_IF_ERROR(EncodePng(shape, [&](int first, int last, uint8_t* out) {
//     ...  // rows [first, last) of host-order samples
//     return absl::OkStatus();
//   }, {file, nullptr}, interrupter));
//
// libpng chooses each row's filter by the smallest sum of absolute
// differences and hands the filtered rows to one zlib stream; only the
// stream is sequential, so the rows and their filters can be made anywhere
// as long as the stream gets them in order with the same settings.
#pragma once

#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <string>

#include "absl/status/status.h"
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
/// disjoint bands; a row may be asked for twice, since a band's filters read
/// the row above it, and must come out the same both times.
using PngRows = std::function<absl::Status(int first, int last, uint8_t* out)>;

/// Encodes the picture `rows` makes into `sink`: the signature, IHDR, IDAT
/// chunks of 8 KiB and IEND, nothing else (no timestamps). Errors: a bad
/// shape, a failing `rows` or sink, or Cancelled when `interrupter` asks.
absl::Status EncodePng(const PngShape& shape, const PngRows& rows, const PngSink& sink,
                       Interrupter* interrupter = nullptr);

/// EncodePng into a new file at `path`; errors other than Cancelled name it.
absl::Status EncodePngFile(const std::filesystem::path& path, const PngShape& shape,
                           const PngRows& rows, Interrupter* interrupter = nullptr);

}  // namespace nimbus
