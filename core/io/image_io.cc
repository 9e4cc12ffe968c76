#include "core/io/image_io.h"

#include <ImfChannelList.h>
#include <ImfFrameBuffer.h>
#include <ImfHeader.h>
#include <ImfInputFile.h>
#include <ImfOutputFile.h>
#include <png.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <memory>
#include <system_error>

#include "absl/strings/str_cat.h"
#include "core/base/status_macros.h"
#include "core/io/file_ptr.h"
#include "core/io/png_io.h"

namespace nimbus {

namespace {

// Samples clamped to [0, 1] (NaN to 0) and rounded to nearest, halves
// up: what std::lround gives on [0, max], without a library call per
// sample (a 1024^2 picture has three million of them).
template <typename T>
void Quantise(const float* in, size_t n, double max, uint8_t* out) {
  for (size_t i = 0; i < n; ++i) {
    const float x = in[i];
    const double v = (x >= 0 ? std::min(double(x), 1.0) : 0.0) * max;
    const int64_t down = int64_t(v);  // v >= 0: truncation is floor
    const T q = T(down + (v - double(down) >= 0.5));  // the difference is exact
    std::memcpy(out + i * sizeof(T), &q, sizeof(T));  // host order
  }
}

void QuantiseRgb(const float* rgb, size_t n, int depth, uint8_t* out) {
  if (depth == 8)
    Quantise<uint8_t>(rgb, n, 255, out);
  else
    Quantise<uint16_t>(rgb, n, 65535, out);
}

// The rows of `image`, quantised.
PngRows QuantisedRows(const RgbImage& image, int depth) {
  return [&image, depth](int first, int last, uint8_t* out) {
    const size_t per_row = 3 * size_t(image.width);
    QuantiseRgb(&image.rgb[size_t(first) * per_row], size_t(last - first) * per_row, depth, out);
    return absl::OkStatus();
  };
}

absl::Status CheckImage(const RgbImage& image) {
  if (image.width <= 0 || image.height <= 0 ||
      image.rgb.size() != 3 * size_t(image.width) * size_t(image.height))
    return absl::InvalidArgumentError("image size does not match its pixels");
  return absl::OkStatus();
}

int PngDepth(ImageFormat format) { return format == ImageFormat::kPng16 ? 16 : 8; }

absl::Status WriteExr(const std::filesystem::path& path, const RgbImage& image) {
  try {
    Imf::Header header(image.width, image.height);
    header.compression() = Imf::ZIP_COMPRESSION;
    const char* names[3] = {"R", "G", "B"};
    for (const char* n : names) header.channels().insert(n, Imf::Channel(Imf::FLOAT));
    Imf::OutputFile file(path.c_str(), header, 1);
    Imf::FrameBuffer fb;
    char* base = const_cast<char*>(reinterpret_cast<const char*>(image.rgb.data()));
    for (int c = 0; c < 3; ++c)
      fb.insert(names[c], Imf::Slice(Imf::FLOAT, base + c * sizeof(float), 3 * sizeof(float),
                                     3 * sizeof(float) * size_t(image.width)));
    file.setFrameBuffer(fb);
    file.writePixels(image.height);
  } catch (const std::exception& e) {
    return absl::InternalError(absl::StrCat("writing ", path.string(), ": ", e.what()));
  }
  return absl::OkStatus();
}

}  // namespace

const char* ImageExtension(ImageFormat format) {
  return format == ImageFormat::kExr ? ".exr" : ".png";
}

absl::Status WriteImage(const std::filesystem::path& path, const RgbImage& image,
                        ImageFormat format) {
  NIMBUS_RETURN_IF_ERROR(CheckImage(image));
  if (format == ImageFormat::kExr)
    return WriteThroughTemp(path,
                            [&](const std::filesystem::path& tmp) { return WriteExr(tmp, image); });
  const int depth = PngDepth(format);
  return WritePngFile(path, {image.width, image.height, depth, 3}, QuantisedRows(image, depth));
}

absl::Status WriteDevelopedImage(const std::filesystem::path& path, const ImageDensity& density,
                                 const LookParams& look, ImageFormat format,
                                 Interrupter* interrupter) {
  if (format == ImageFormat::kExr || HasGlow(look.glow, look.glow_radius)) {
    NIMBUS_ASSIGN_OR_RETURN(RgbImage rgb, DevelopImage(density, look, interrupter));
    return WriteImage(path, rgb, format);
  }
  const Developer developer(density, look);
  const int depth = PngDepth(format);
  auto rows = [&](int first, int last, uint8_t* out) {
    const size_t n = 3 * size_t(density.width) * size_t(last - first);
    std::vector<float> rgb(n);
    developer.Rows(first, last, rgb.data());
    QuantiseRgb(rgb.data(), n, depth, out);
    return absl::OkStatus();
  };
  return WritePngFile(path, {density.width, density.height, depth, 3}, rows, interrupter);
}

absl::StatusOr<std::string> EncodePng8(const RgbImage& image) {
  NIMBUS_RETURN_IF_ERROR(CheckImage(image));
  std::string bytes;
  NIMBUS_RETURN_IF_ERROR(
      WritePng({image.width, image.height, 8, 3}, QuantisedRows(image, 8), {nullptr, &bytes}));
  return bytes;
}

absl::StatusOr<PngPixels> ReadPngPixels(const std::filesystem::path& path) {
  FilePtr f(std::fopen(path.c_str(), "rb"));
  if (!f) return absl::NotFoundError(absl::StrCat("cannot open ", path.string()));
  png_structp png = png_create_read_struct(PNG_LIBPNG_VER_STRING, nullptr, nullptr, nullptr);
  png_infop info = png ? png_create_info_struct(png) : nullptr;
  if (!info) {
    png_destroy_read_struct(&png, nullptr, nullptr);
    return absl::InternalError("libpng");
  }
  PngPixels* out = new PngPixels;  // raw: survives a longjmp without leaking its buffer
  if (setjmp(png_jmpbuf(png))) {
    png_destroy_read_struct(&png, &info, nullptr);
    delete out;
    return absl::InvalidArgumentError(absl::StrCat("reading ", path.string(), " failed"));
  }
  png_init_io(png, f.get());
  png_read_png(png, info, PNG_TRANSFORM_SWAP_ENDIAN, nullptr);
  out->width = int(png_get_image_width(png, info));
  out->height = int(png_get_image_height(png, info));
  out->bit_depth = png_get_bit_depth(png, info);
  out->channels = png_get_channels(png, info);
  png_bytepp rows = png_get_rows(png, info);
  const size_t per_row = size_t(out->width) * size_t(out->channels);
  out->samples.resize(per_row * size_t(out->height));
  for (int r = 0; r < out->height; ++r)
    for (size_t i = 0; i < per_row; ++i)
      out->samples[size_t(r) * per_row + i] =
          out->bit_depth == 16 ? reinterpret_cast<const uint16_t*>(rows[r])[i] : rows[r][i];
  png_destroy_read_struct(&png, &info, nullptr);
  PngPixels result = std::move(*out);
  delete out;
  return result;
}

absl::StatusOr<RgbImage> ReadExr(const std::filesystem::path& path) {
  try {
    Imf::InputFile file(path.c_str());
    const Imath::Box2i dw = file.header().dataWindow();
    RgbImage out;
    out.width = dw.max.x - dw.min.x + 1;
    out.height = dw.max.y - dw.min.y + 1;
    out.rgb.assign(3 * size_t(out.width) * size_t(out.height), 0.f);
    Imf::FrameBuffer fb;
    const char* names[3] = {"R", "G", "B"};
    char* base = reinterpret_cast<char*>(out.rgb.data()) -
                 3 * sizeof(float) * (size_t(dw.min.x) + size_t(dw.min.y) * size_t(out.width));
    for (int c = 0; c < 3; ++c)
      fb.insert(names[c], Imf::Slice(Imf::FLOAT, base + c * sizeof(float), 3 * sizeof(float),
                                     3 * sizeof(float) * size_t(out.width)));
    file.setFrameBuffer(fb);
    file.readPixels(dw.min.y, dw.max.y);
    return out;
  } catch (const std::exception& e) {
    return absl::InvalidArgumentError(absl::StrCat("reading ", path.string(), ": ", e.what()));
  }
}

}  // namespace nimbus
