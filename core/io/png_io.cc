#include "core/io/png_io.h"

#include <png.h>
#include <tbb/parallel_pipeline.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <atomic>
#include <bit>
#include <cerrno>
#include <cstring>
#include <memory>

#include "absl/strings/str_cat.h"
#include "core/base/status_macros.h"
#include "core/io/file_ptr.h"

namespace nimbus {

namespace {

// About this many bytes of rows per band: enough to keep libpng's thread
// fed, few enough that a band stays in L2.
constexpr size_t kBandBytes = size_t{128} << 10;

// What libpng's callbacks report back: the sink's first error (errno) and
// libpng's own message.
struct WriteState {
  const PngSink* sink = nullptr;
  int sink_errno = 0;
  char message[160] = {};
};

void OnError(png_structp png, png_const_charp message) {
  auto* s = static_cast<WriteState*>(png_get_error_ptr(png));
  std::snprintf(s->message, sizeof s->message, "%s", message);
  png_longjmp(png, 1);
}
void OnWarning(png_structp, png_const_charp) {}

void OnWrite(png_structp png, png_bytep data, png_size_t n) {
  auto* s = static_cast<WriteState*>(png_get_io_ptr(png));
  if (s->sink->file != nullptr) {
    if (std::fwrite(data, 1, n, s->sink->file) != n) {
      s->sink_errno = errno != 0 ? errno : EIO;
      png_error(png, "write failed");
    }
  } else {
    s->sink->bytes->append(reinterpret_cast<const char*>(data), n);
  }
}
void OnFlush(png_structp) {}

struct PngWriteStruct {
  png_structp png = nullptr;
  png_infop info = nullptr;
  ~PngWriteStruct() { png_destroy_write_struct(&png, info ? &info : nullptr); }
};

// libpng reports errors by longjmp back here: nothing with a destructor
// lives in these frames, and each call sets its own jump target.
bool WriteHeader(PngWriteStruct& w, const PngShape& s) {
  if (setjmp(png_jmpbuf(w.png))) return false;
  png_set_IHDR(w.png, w.info, png_uint_32(s.width), png_uint_32(s.height), s.depth,
               s.channels == 1 ? PNG_COLOR_TYPE_GRAY : PNG_COLOR_TYPE_RGB, PNG_INTERLACE_NONE,
               PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
  png_write_info(w.png, w.info);
  // PNG stores 16-bit samples big-endian; the rows come in host order.
  if (s.depth == 16 && std::endian::native == std::endian::little) png_set_swap(w.png);
  return true;
}
bool WriteRows(PngWriteStruct& w, png_bytepp rows, png_uint_32 n) {
  if (setjmp(png_jmpbuf(w.png))) return false;
  png_write_rows(w.png, rows, n);
  return true;
}
bool WriteEnd(PngWriteStruct& w) {
  if (setjmp(png_jmpbuf(w.png))) return false;
  png_write_end(w.png, nullptr);
  return true;
}

absl::Status LibpngError(const WriteState& state) {
  if (state.sink_errno != 0)
    return absl::ErrnoToStatus(state.sink_errno, "png: write failed");
  return absl::InternalError(absl::StrCat("png: libpng: ", state.message));
}

absl::Status CheckShape(const PngShape& s) {
  if (s.width <= 0 || s.height <= 0 || s.width > (1 << 30) || s.height > (1 << 30))
    return absl::InvalidArgumentError(
        absl::StrCat("png: a ", s.width, " x ", s.height, " picture has no valid size"));
  if ((s.depth != 8 && s.depth != 16) || (s.channels != 1 && s.channels != 3))
    return absl::InvalidArgumentError(absl::StrCat("png: ", s.channels, " channels of ", s.depth,
                                                   " bits is not a supported layout"));
  return absl::OkStatus();
}

// A band of rows on its way to libpng.
struct Band {
  int first = 0, last = 0;
  std::vector<uint8_t> samples;
  absl::Status status;
};

// Makes bands in parallel and hands them to libpng in order; the first
// error (or cancellation) stops the bands not yet started.
absl::Status RunBands(const PngShape& s, const PngRows& rows, PngWriteStruct& w,
                      const WriteState& state, Interrupter* interrupter) {
  const size_t row_bytes = s.RowBytes();
  const int per_band = int(std::clamp<size_t>(kBandBytes / row_bytes, 1, size_t(s.height)));
  Interrupter& intr = OrNull(interrupter);
  std::atomic<bool> stop{false}, cancelled{false};
  absl::Status status;  // written by the serial last stage only
  int next = 0;
  auto issue = [&](tbb::flow_control& fc) -> Band* {
    if (next >= s.height || stop.load(std::memory_order_relaxed)) {
      fc.stop();
      return nullptr;
    }
    if (intr.WasInterrupted(uint64_t(next), uint64_t(s.height))) {
      cancelled = true;
      fc.stop();
      return nullptr;
    }
    auto* b = new Band;
    b->first = next;
    b->last = next = std::min(s.height, next + per_band);
    return b;
  };
  auto make = [&](Band* b) {
    b->samples.resize(size_t(b->last - b->first) * row_bytes);
    b->status = rows(b->first, b->last, b->samples.data());
    return b;
  };
  auto write = [&](Band* raw) {
    std::unique_ptr<Band> b(raw);
    if (!status.ok()) return;
    status = b->status;
    std::vector<png_bytep> ptrs(size_t(b->last - b->first));
    for (size_t k = 0; k < ptrs.size(); ++k) ptrs[k] = &b->samples[k * row_bytes];
    if (status.ok() && !WriteRows(w, ptrs.data(), png_uint_32(ptrs.size())))
      status = LibpngError(state);
    if (!status.ok()) stop = true;
  };
  const size_t tokens = 4 * size_t(tbb::this_task_arena::max_concurrency());
  tbb::parallel_pipeline(
      tokens, tbb::make_filter<void, Band*>(tbb::filter_mode::serial_in_order, issue) &
                  tbb::make_filter<Band*, Band*>(tbb::filter_mode::parallel, make) &
                  tbb::make_filter<Band*, void>(tbb::filter_mode::serial_in_order, write));
  NIMBUS_RETURN_IF_ERROR(status);
  if (cancelled) return absl::CancelledError("interrupted");
  return absl::OkStatus();
}

// The status of a failed file write: a full disk or quota (ENOSPC and
// EDQUOT are RESOURCE_EXHAUSTED as errno statuses) is the client's
// RESOURCE_EXHAUSTED, anything else INTERNAL; both name the file only.
absl::Status FileError(const std::filesystem::path& path, const absl::Status& st) {
  if (absl::IsCancelled(st) || absl::IsInvalidArgument(st)) return st;
  const std::string detail = absl::StrCat(path.filename().string(), ": ", st.message());
  if (absl::IsResourceExhausted(st))
    return absl::ResourceExhaustedError(
        absl::StrCat("disk full while writing the result: ", detail));
  return absl::InternalError(absl::StrCat("cannot write the result: ", detail));
}

}  // namespace

absl::Status WritePng(const PngShape& shape, const PngRows& rows, const PngSink& sink,
                      Interrupter* interrupter) {
  NIMBUS_RETURN_IF_ERROR(CheckShape(shape));
  WriteState state;
  state.sink = &sink;
  PngWriteStruct w;
  w.png = png_create_write_struct(PNG_LIBPNG_VER_STRING, &state, OnError, OnWarning);
  if (w.png != nullptr) w.info = png_create_info_struct(w.png);
  if (w.info == nullptr) return absl::InternalError("png: libpng could not start");
  png_set_write_fn(w.png, &state, OnWrite, OnFlush);
  if (!WriteHeader(w, shape)) return LibpngError(state);
  NIMBUS_RETURN_IF_ERROR(RunBands(shape, rows, w, state, interrupter));
  if (!WriteEnd(w)) return LibpngError(state);
  return absl::OkStatus();
}

absl::Status WritePngFile(const std::filesystem::path& path, const PngShape& shape,
                          const PngRows& rows, Interrupter* interrupter) {
  absl::Status st = WriteThroughTemp(path, [&](const std::filesystem::path& tmp) {
    FilePtr f(std::fopen(tmp.c_str(), "wb"));
    if (!f) return absl::ErrnoToStatus(errno, "cannot create the file");
    NIMBUS_RETURN_IF_ERROR(WritePng(shape, rows, {f.get(), nullptr}, interrupter));
    if (std::fflush(f.get()) != 0) return absl::ErrnoToStatus(errno, "png: flush failed");
    if (std::fclose(f.release()) != 0) return absl::ErrnoToStatus(errno, "png: close failed");
    return absl::OkStatus();
  });
  return st.ok() ? st : FileError(path, st);
}

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
  return WritePngFile(path, shape, rows);
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
