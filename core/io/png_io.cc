#include "core/io/png_io.h"

#include <png.h>

#include <cstring>

#include "absl/strings/str_cat.h"
#include "core/io/file_ptr.h"
#include "core/io/png_encoder.h"

namespace nimbus {

absl::Status WritePng16(const std::filesystem::path& path, const Gray16Image& image) {
  if (image.width <= 0 || image.height <= 0 ||
      image.pixels.size() != size_t(image.width) * size_t(image.height))
    return absl::InvalidArgumentError("png: image size does not match its pixels");
  const PngShape shape{image.width, image.height, 16, 1};
  auto rows = [&](int first, int last, uint8_t* out) {
    std::memcpy(out, &image.pixels[size_t(first) * size_t(image.width)],
                size_t(last - first) * shape.RowBytes());
    return absl::OkStatus();
  };
  return WriteThroughTemp(
      path, [&](const std::filesystem::path& tmp) { return EncodePngFile(tmp, shape, rows); });
}

absl::StatusOr<Gray16Image> ReadPng16(const std::filesystem::path& path) {
  png_image img{};
  img.version = PNG_IMAGE_VERSION;
  if (!png_image_begin_read_from_file(&img, path.c_str()))
    return absl::InvalidArgumentError(absl::StrCat("reading ", path.string(), ": ", img.message));
  img.format = PNG_FORMAT_LINEAR_Y;  // 16-bit grey, host order
  Gray16Image out;
  out.width = int(img.width);
  out.height = int(img.height);
  out.pixels.resize(size_t(out.width) * size_t(out.height));
  if (!png_image_finish_read(&img, nullptr, out.pixels.data(), 0, nullptr))
    return absl::InvalidArgumentError(absl::StrCat("reading ", path.string(), ": ", img.message));
  return out;
}

}  // namespace nimbus
