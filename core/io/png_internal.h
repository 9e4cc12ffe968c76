// The one libpng writer behind the height maps (png_io) and the pictures
// (image_io). Internal to core/io.
#pragma once

#include <png.h>

#include <cstdio>
#include <string>

namespace nimbus {

/// Where the PNG goes: an open file, or else a growing string.
struct PngSink {
  FILE* file = nullptr;
  std::string* bytes = nullptr;
};

/// Writes `height` rows of host-order samples, `channels` 1 (grey) or 3
/// (RGB) per pixel, `depth` 8 or 16 bits. False when libpng fails.
bool WritePngRows(const PngSink& sink, int width, int height, int depth, int channels,
                  png_bytep* rows);

}  // namespace nimbus
