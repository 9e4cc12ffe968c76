#include "core/io/png_encoder.h"

#include <tbb/parallel_pipeline.h>
#include <tbb/task_arena.h>
#include <zlib.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cstring>
#include <memory>
#include <vector>

#include "absl/strings/str_cat.h"
#include "core/base/status_macros.h"
#include "core/io/file_ptr.h"

namespace nimbus {

namespace {

// PNG's filter types, in the order libpng tries them.
enum Filter : uint8_t { kNone = 0, kSub = 1, kUp = 2, kAvg = 3, kPaeth = 4 };
constexpr int kFilters = 5;

// libpng's output buffer, and so the size of every IDAT chunk but the last.
constexpr size_t kChunkBytes = 8192;
// About this many bytes of rows per band: enough to keep the deflating
// thread fed, few enough that a band's buffers stay in L2.
constexpr size_t kBandBytes = size_t{128} << 10;

// The filters libpng tries: all five, except that a single row has no row
// above and a single column no pixel to the left.
std::array<bool, kFilters> AllowedFilters(const PngShape& s) {
  std::array<bool, kFilters> on{true, true, true, true, true};
  if (s.height == 1) on[kUp] = on[kAvg] = on[kPaeth] = false;
  if (s.width == 1) on[kSub] = on[kAvg] = on[kPaeth] = false;
  return on;
}

bool OnlyNone(const std::array<bool, kFilters>& on) {
  return !on[kSub] && !on[kUp] && !on[kAvg] && !on[kPaeth];
}

// libpng's cost of a filtered byte: its distance from zero, reading bytes
// from 128 up as negative.
inline size_t Cost(const uint8_t* p, size_t n) {
  size_t sum = 0;
  for (size_t i = 0; i < n; ++i) sum += p[i] < 128 ? p[i] : 256 - p[i];
  return sum;
}

inline uint8_t PaethPredictor(int a, int b, int c) {
  const int p = b - c, q = a - c;
  const int pa = std::abs(p), pb = std::abs(q), pc = std::abs(p + q);
  return uint8_t(pa <= pb && pa <= pc ? a : pb <= pc ? b : c);
}

// The row `cur` (n bytes, `bpp` per pixel, `prev` above it) under the
// sub, up, average and Paeth filters, n bytes each into `out`. Every
// filter reads unfiltered bytes only, so the loops vectorise.
void FilterCandidates(const uint8_t* prev, const uint8_t* cur, size_t n, size_t bpp, uint8_t* out) {
  uint8_t *sub = out, *up = out + n, *avg = out + 2 * n, *paeth = out + 3 * n;
  for (size_t i = 0; i < bpp; ++i) {
    sub[i] = cur[i];
    up[i] = paeth[i] = uint8_t(cur[i] - prev[i]);
    avg[i] = uint8_t(cur[i] - (prev[i] >> 1));
  }
  for (size_t i = bpp; i < n; ++i) {
    sub[i] = uint8_t(cur[i] - cur[i - bpp]);
    up[i] = uint8_t(cur[i] - prev[i]);
    avg[i] = uint8_t(cur[i] - ((prev[i] + cur[i - bpp]) >> 1));
    paeth[i] = uint8_t(cur[i] - PaethPredictor(cur[i - bpp], prev[i], prev[i - bpp]));
  }
}

// The filter byte and the filtered row into `out` (n + 1 bytes): the
// allowed filter of least cost, the first in PNG's order on a tie. libpng
// stops summing a filter once it exceeds the best so far, which never
// changes the choice. `scratch` holds 4n bytes.
void FilterRow(const uint8_t* prev, const uint8_t* cur, size_t n, size_t bpp,
               const std::array<bool, kFilters>& on, uint8_t* scratch, uint8_t* out) {
  const uint8_t* best = cur;
  uint8_t type = kNone;
  if (!OnlyNone(on)) {
    FilterCandidates(prev, cur, n, bpp, scratch);
    size_t least = Cost(cur, n);
    for (int f = kSub; f < kFilters; ++f) {
      if (!on[size_t(f)]) continue;
      const uint8_t* row = scratch + size_t(f - 1) * n;
      if (const size_t c = Cost(row, n); c < least) {
        least = c;
        best = row;
        type = uint8_t(f);
      }
    }
  }
  out[0] = type;
  std::memcpy(out + 1, best, n);
}

void PutBigEndian(uint32_t v, uint8_t* out) {
  for (int i = 0; i < 4; ++i) out[i] = uint8_t(v >> (24 - 8 * i));
}

absl::Status Write(const PngSink& sink, const void* data, size_t n) {
  if (n == 0) return absl::OkStatus();
  if (sink.file) {
    if (std::fwrite(data, 1, n, sink.file) != n) return absl::InternalError("png: write failed");
  } else {
    sink.bytes->append(static_cast<const char*>(data), n);
  }
  return absl::OkStatus();
}

// Length, type, data and the CRC of type and data.
absl::Status WriteChunk(const PngSink& sink, const char type[4], const uint8_t* data, size_t n) {
  uint8_t head[8], tail[4];
  PutBigEndian(uint32_t(n), head);
  std::memcpy(head + 4, type, 4);
  uLong crc = crc32(0, reinterpret_cast<const Bytef*>(type), 4);
  if (n > 0) crc = crc32(crc, data, uInt(n));  // crc32 of a null buffer is 0, not crc
  PutBigEndian(uint32_t(crc), tail);
  NIMBUS_RETURN_IF_ERROR(Write(sink, head, 8));
  NIMBUS_RETURN_IF_ERROR(Write(sink, data, n));
  return Write(sink, tail, 4);
}

absl::Status WriteHeader(const PngSink& sink, const PngShape& s) {
  static constexpr uint8_t kSignature[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
  NIMBUS_RETURN_IF_ERROR(Write(sink, kSignature, 8));
  uint8_t ihdr[13] = {};
  PutBigEndian(uint32_t(s.width), ihdr);
  PutBigEndian(uint32_t(s.height), ihdr + 4);
  ihdr[8] = uint8_t(s.depth);
  ihdr[9] = s.channels == 1 ? 0 : 2;  // grey or RGB; compression, filter, interlace 0
  return WriteChunk(sink, "IHDR", ihdr, 13);
}

// libpng's size of the filtered image data, for sizing the zlib window.
uint64_t FilteredSize(const PngShape& s) {
  const uint64_t row = s.RowBytes();
  return row < 32768 && s.height < 32768 ? (row + 1) * uint64_t(s.height) : 0xffffffffu;
}

// libpng's window: the smallest that still sees the whole of a small
// image plus zlib's 262 bytes of lookahead.
int WindowBits(uint64_t size) {
  int bits = 15;
  if (size <= 16384)
    for (uint64_t half = 1u << 14; size + 262 <= half; half >>= 1) --bits;
  return bits;
}

// libpng's rewrite of the zlib header in the first IDAT: the window field
// lowered to the smallest that covers `size`, the check bits redone.
void TightenHeader(uint8_t* z, uint64_t size) {
  if (size > 16384 || (z[0] & 0x0f) != 8 || (z[0] & 0xf0) > 0x70) return;
  unsigned info = z[0] >> 4;
  uint64_t half = uint64_t{1} << (info + 7);
  if (size > half) return;
  do {
    half >>= 1;
    --info;
  } while (info > 0 && size <= half);
  z[0] = uint8_t((z[0] & 0x0f) | (info << 4));
  unsigned flags = z[1] & 0xe0u;
  flags += 0x1f - ((unsigned(z[0]) << 8) + flags) % 0x1f;
  z[1] = uint8_t(flags);
}

// The zlib stream and its IDAT chunks, driven call for call as libpng
// drives them: one deflate per filtered row without flushing, a chunk each
// time the 8 KiB buffer fills, then Z_FINISH.
class IdatStream {
 public:
  IdatStream(const PngShape& shape, bool filtered, const PngSink& sink)
      : size_(FilteredSize(shape)), filtered_(filtered), sink_(sink) {}
  ~IdatStream() {
    if (started_) deflateEnd(&z_);
  }
  IdatStream(const IdatStream&) = delete;
  IdatStream& operator=(const IdatStream&) = delete;

  absl::Status Start() {
    // libpng's defaults: level 6, memory level 8, Z_FILTERED unless no row
    // can be filtered.
    if (deflateInit2(&z_, Z_DEFAULT_COMPRESSION, Z_DEFLATED, WindowBits(size_), 8,
                     filtered_ ? Z_FILTERED : Z_DEFAULT_STRATEGY) != Z_OK)
      return absl::ResourceExhaustedError("png: zlib could not start");
    started_ = true;
    ResetOutput();
    return absl::OkStatus();
  }

  absl::Status AddRow(const uint8_t* row, size_t n) {
    z_.next_in = const_cast<Bytef*>(row);
    z_.avail_in = uInt(n);
    while (true) {
      const int ret = deflate(&z_, Z_NO_FLUSH);
      if (z_.avail_out == 0) NIMBUS_RETURN_IF_ERROR(EmitChunk(kChunkBytes));
      if (ret != Z_OK) return absl::InternalError(absl::StrCat("png: zlib error ", ret));
      if (z_.avail_in == 0) return absl::OkStatus();
    }
  }

  absl::Status Finish() {
    z_.next_in = nullptr;
    z_.avail_in = 0;
    while (true) {
      const int ret = deflate(&z_, Z_FINISH);
      if (z_.avail_out == 0) {
        NIMBUS_RETURN_IF_ERROR(EmitChunk(kChunkBytes));
        if (ret == Z_OK) continue;
      }
      if (ret == Z_STREAM_END) return EmitChunk(kChunkBytes - z_.avail_out);
      return absl::InternalError(absl::StrCat("png: zlib error ", ret, " on finishing"));
    }
  }

 private:
  void ResetOutput() {
    z_.next_out = out_.data();
    z_.avail_out = uInt(kChunkBytes);
  }

  absl::Status EmitChunk(size_t n) {
    if (n == 0) return absl::OkStatus();
    if (first_) TightenHeader(out_.data(), size_);
    first_ = false;
    NIMBUS_RETURN_IF_ERROR(WriteChunk(sink_, "IDAT", out_.data(), n));
    ResetOutput();
    return absl::OkStatus();
  }

  const uint64_t size_;
  const bool filtered_;
  const PngSink& sink_;
  z_stream z_{};
  bool started_ = false, first_ = true;
  std::array<uint8_t, kChunkBytes> out_{};
};

// A band of rows on its way through the pipeline: made with the row above
// it (zeros above the first), filtered, then deflated.
struct Band {
  int first = 0, last = 0;
  std::vector<uint8_t> raw, filtered;
  absl::Status status;
};

void SwapSamples(uint8_t* p, size_t n) {
  for (size_t i = 0; i + 1 < n; i += 2) std::swap(p[i], p[i + 1]);
}

// PNG stores 16-bit samples big-endian; the rows come in host order.
absl::Status MakeBand(const PngShape& s, const PngRows& rows, Band& b) {
  const size_t rb = s.RowBytes(), count = size_t(b.last - b.first);
  b.raw.resize((count + 1) * rb);
  if (b.first == 0) {
    std::fill_n(b.raw.begin(), rb, uint8_t{0});
    NIMBUS_RETURN_IF_ERROR(rows(0, b.last, b.raw.data() + rb));
  } else {
    NIMBUS_RETURN_IF_ERROR(rows(b.first - 1, b.last, b.raw.data()));
  }
  if (s.depth == 16) SwapSamples(b.raw.data(), b.raw.size());
  return absl::OkStatus();
}

void FilterBand(const PngShape& s, const std::array<bool, kFilters>& on, Band& b) {
  const size_t rb = s.RowBytes(), bpp = size_t(s.channels) * size_t(s.depth / 8);
  const size_t count = size_t(b.last - b.first);
  b.filtered.resize(count * (rb + 1));
  std::vector<uint8_t> scratch(4 * rb);
  for (size_t k = 0; k < count; ++k)
    FilterRow(&b.raw[k * rb], &b.raw[(k + 1) * rb], rb, bpp, on, scratch.data(),
              &b.filtered[k * (rb + 1)]);
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

// Makes and filters bands in parallel and deflates them in order; the
// first error (or cancellation) stops the bands not yet started.
absl::Status RunBands(const PngShape& s, const PngRows& rows, IdatStream& idat,
                      Interrupter* interrupter) {
  const std::array<bool, kFilters> on = AllowedFilters(s);
  const int per_band = int(std::clamp<size_t>(kBandBytes / s.RowBytes(), 1, size_t(s.height)));
  Interrupter& intr = OrNull(interrupter);
  std::atomic<bool> stop{false};
  absl::Status status;  // written by the serial last stage only
  int next = 0;
  const size_t tokens = 4 * size_t(tbb::this_task_arena::max_concurrency());
  tbb::parallel_pipeline(
      tokens, tbb::make_filter<void, Band*>(
                  tbb::filter_mode::serial_in_order,
                  [&](tbb::flow_control& fc) -> Band* {
                    if (next >= s.height || stop.load(std::memory_order_relaxed)) {
                      fc.stop();
                      return nullptr;
                    }
                    if (intr.WasInterrupted(uint64_t(next), uint64_t(s.height))) {
                      stop = true;
                      fc.stop();
                      return nullptr;
                    }
                    auto* b = new Band;
                    b->first = next;
                    b->last = next = std::min(s.height, next + per_band);
                    return b;
                  }) &
                  tbb::make_filter<Band*, Band*>(tbb::filter_mode::parallel,
                                                 [&](Band* b) {
                                                   b->status = MakeBand(s, rows, *b);
                                                   if (b->status.ok()) FilterBand(s, on, *b);
                                                   return b;
                                                 }) &
                  tbb::make_filter<Band*, void>(tbb::filter_mode::serial_in_order, [&](Band* raw) {
                    std::unique_ptr<Band> b(raw);
                    if (!status.ok()) return;
                    status = b->status;
                    const size_t row = s.RowBytes() + 1;
                    for (size_t k = 0; status.ok() && k < size_t(b->last - b->first); ++k)
                      status = idat.AddRow(&b->filtered[k * row], row);
                    if (!status.ok()) stop = true;
                  }));
  NIMBUS_RETURN_IF_ERROR(status);
  if (stop) return absl::CancelledError("interrupted");
  return absl::OkStatus();
}

}  // namespace

absl::Status EncodePng(const PngShape& shape, const PngRows& rows, const PngSink& sink,
                       Interrupter* interrupter) {
  NIMBUS_RETURN_IF_ERROR(CheckShape(shape));
  IdatStream idat(shape, !OnlyNone(AllowedFilters(shape)), sink);
  NIMBUS_RETURN_IF_ERROR(WriteHeader(sink, shape));
  NIMBUS_RETURN_IF_ERROR(idat.Start());
  NIMBUS_RETURN_IF_ERROR(RunBands(shape, rows, idat, interrupter));
  NIMBUS_RETURN_IF_ERROR(idat.Finish());
  return WriteChunk(sink, "IEND", nullptr, 0);
}

absl::Status EncodePngFile(const std::filesystem::path& path, const PngShape& shape,
                           const PngRows& rows, Interrupter* interrupter) {
  FilePtr f(std::fopen(path.c_str(), "wb"));
  if (!f) return absl::InternalError(absl::StrCat("cannot create ", path.string()));
  absl::Status st = EncodePng(shape, rows, {f.get(), nullptr}, interrupter);
  if (st.ok() && std::fflush(f.get()) != 0) st = absl::InternalError("flushing failed");
  if (!st.ok() && !absl::IsCancelled(st))
    return absl::InternalError(absl::StrCat("writing ", path.string(), ": ", st.message()));
  return st;
}

}  // namespace nimbus
