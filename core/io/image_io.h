// @brief Colour picture files: 8- and 16-bit RGB PNG (through libpng,
// png_io.h) and float RGB OpenEXR. The libraries stay
// behind this header.
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "core/grid/image_look.h"

namespace nimbus {

enum class ImageFormat { kPng8, kPng16, kExr };

/// ".png" or ".exr".
const char* ImageExtension(ImageFormat format);

/// Writes `image` (values clamped to [0, 1] and quantised for PNG; as
/// 32-bit floats for EXR) through a temporary file renamed into place. No
/// timestamps: the same image gives the same bytes.
absl::Status WriteImage(const std::filesystem::path& path, const RgbImage& image,
                        ImageFormat format);

/// Develops `density` with `look` (DevelopImage) and writes it as
/// WriteImage does. A PNG without glow is developed a band of rows at a
/// time while libpng encodes it (WritePng), so the float picture never
/// exists whole; the bytes are the same either way.
absl::Status WriteDevelopedImage(const std::filesystem::path& path, const ImageDensity& density,
                                 const LookParams& look, ImageFormat format,
                                 Interrupter* interrupter);

/// An 8-bit RGB PNG in memory (previews).
absl::StatusOr<std::string> EncodePng8(const RgbImage& image);

/// @brief A PNG read back as it is stored: 8 or 16 bits per sample.
struct PngPixels {
  int width = 0, height = 0, bit_depth = 0, channels = 0;
  std::vector<uint16_t> samples;  // row-major, channels per pixel
};
absl::StatusOr<PngPixels> ReadPngPixels(const std::filesystem::path& path);
/// An EXR's R, G, B channels as floats.
absl::StatusOr<RgbImage> ReadExr(const std::filesystem::path& path);

}  // namespace nimbus
