#include "core/io/png_io.h"

#include <cstdio>
#include <memory>
#include <system_error>

#include "absl/strings/str_cat.h"
#include "core/io/file_ptr.h"
#include "core/io/png_internal.h"

namespace nimbus {

namespace {

void WriteToString(png_structp png, png_bytep data, png_size_t n) {
  static_cast<std::string*>(png_get_io_ptr(png))->append(reinterpret_cast<char*>(data), n);
}
void FlushNothing(png_structp) {}

}  // namespace

// libpng reports errors by longjmp; nothing with a destructor lives
// between the setjmp and the calls that may jump.
bool WritePngRows(const PngSink& sink, int width, int height, int depth, int channels,
                  png_bytep* rows) {
  png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, nullptr, nullptr, nullptr);
  if (!png) return false;
  png_infop info = png_create_info_struct(png);
  if (!info || setjmp(png_jmpbuf(png))) {
    png_destroy_write_struct(&png, info ? &info : nullptr);
    return false;
  }
  if (sink.file)
    png_init_io(png, sink.file);
  else
    png_set_write_fn(png, sink.bytes, WriteToString, FlushNothing);
  png_set_IHDR(png, info, png_uint_32(width), png_uint_32(height), depth,
               channels == 1 ? PNG_COLOR_TYPE_GRAY : PNG_COLOR_TYPE_RGB, PNG_INTERLACE_NONE,
               PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
  png_write_info(png, info);
  if (depth == 16) png_set_swap(png);  // PNG is big-endian; samples are host order
  png_write_image(png, rows);
  png_write_end(png, nullptr);
  png_destroy_write_struct(&png, &info);
  return true;
}

absl::Status WritePng16(const std::filesystem::path& path, const Gray16Image& image) {
  if (image.width <= 0 || image.height <= 0 ||
      image.pixels.size() != size_t(image.width) * size_t(image.height))
    return absl::InvalidArgumentError("png: image size does not match its pixels");
  const std::filesystem::path tmp = path.string() + ".partial";
  std::vector<png_bytep> rows(size_t(image.height));
  for (int r = 0; r < image.height; ++r)
    rows[size_t(r)] = reinterpret_cast<png_bytep>(
        const_cast<uint16_t*>(&image.pixels[size_t(r) * size_t(image.width)]));
  {
    FilePtr f(std::fopen(tmp.c_str(), "wb"));
    if (!f) return absl::InternalError(absl::StrCat("cannot create ", tmp.string()));
    if (!WritePngRows({f.get(), nullptr}, image.width, image.height, 16, 1, rows.data()) ||
        std::fflush(f.get()) != 0) {
      f.reset();
      std::error_code ec;
      std::filesystem::remove(tmp, ec);
      return absl::InternalError(absl::StrCat("writing ", path.string(), " failed"));
    }
  }
  std::error_code ec;
  std::filesystem::rename(tmp, path, ec);
  if (ec) return absl::InternalError(absl::StrCat("renaming ", tmp.string(), ": ", ec.message()));
  return absl::OkStatus();
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
