#include "tests/support/libpng_writer.h"

#include <png.h>

namespace nimbus::testing {

namespace {

void Append(png_structp png, png_bytep data, png_size_t n) {
  static_cast<std::string*>(png_get_io_ptr(png))->append(reinterpret_cast<char*>(data), n);
}
void FlushNothing(png_structp) {}

}  // namespace

// libpng reports errors by longjmp; the rows and the output live outside
// the setjmp frame, so nothing with a destructor is skipped.
std::string LibpngEncode(const PngShape& shape, const std::vector<uint8_t>& samples) {
  std::vector<png_bytep> rows(size_t(shape.height));
  for (size_t r = 0; r < rows.size(); ++r)
    rows[r] = const_cast<png_bytep>(&samples[r * shape.RowBytes()]);
  std::string out;
  png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, nullptr, nullptr, nullptr);
  png_infop info = png ? png_create_info_struct(png) : nullptr;
  if (!info || setjmp(png_jmpbuf(png))) {
    png_destroy_write_struct(&png, info ? &info : nullptr);
    return {};
  }
  png_set_write_fn(png, &out, Append, FlushNothing);
  png_set_IHDR(png, info, png_uint_32(shape.width), png_uint_32(shape.height), shape.depth,
               shape.channels == 1 ? PNG_COLOR_TYPE_GRAY : PNG_COLOR_TYPE_RGB, PNG_INTERLACE_NONE,
               PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
  png_write_info(png, info);
  if (shape.depth == 16) png_set_swap(png);  // PNG is big-endian
  png_write_image(png, rows.data());
  png_write_end(png, nullptr);
  png_destroy_write_struct(&png, &info);
  return out;
}

}  // namespace nimbus::testing
