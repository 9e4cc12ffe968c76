#include "core/grid/image_look.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <vector>

#include "core/base/status_macros.h"

namespace nimbus {

namespace {

// Rows per parallel task and per interrupter poll.
constexpr int kRowBlock = 16;

// Runs f(row) for every row in blocks, in parallel; each row's result
// depends on that row only, so the output is the same for any thread count.
template <typename F>
absl::Status ForRows(int rows, Interrupter* interrupter, F&& f) {
  Interrupter& intr = OrNull(interrupter);
  std::atomic<bool> stop{false};
  const int blocks = (rows + kRowBlock - 1) / kRowBlock;
  tbb::parallel_for(0, blocks, [&](int b) {
    if (stop.load(std::memory_order_relaxed)) return;
    if (intr.WasInterrupted(uint64_t(b), uint64_t(blocks))) {
      stop = true;
      return;
    }
    for (int r = b * kRowBlock; r < std::min(rows, (b + 1) * kRowBlock); ++r) f(r);
  });
  if (stop) return absl::CancelledError("interrupted");
  return absl::OkStatus();
}

// Each part's tiles by tile index, so that the filter reads counters
// straight from their tiles instead of one CountGrid::Get call (and its
// key arithmetic) per sample.
struct PartTiles {
  std::vector<const uint32_t*> counts;
  std::vector<const uint64_t*> colors;  // null without colour
};

PartTiles IndexTiles(const CountGrid& g) {
  const Int3 t = g.tiles();
  PartTiles out;
  const size_t n = size_t(t.x) * size_t(t.y) * size_t(t.z);
  out.counts.assign(n, nullptr);
  out.colors.assign(n, nullptr);
  g.ForEachTileWithColor([&](Int3 origin, const uint32_t* counts, const uint64_t* colors) {
    const size_t i = (size_t(origin.x / CountGrid::kTileDim) * size_t(t.y) +
                      size_t(origin.y / CountGrid::kTileDim)) *
                         size_t(t.z) +
                     size_t(origin.z / CountGrid::kTileDim);
    out.counts[i] = counts;
    out.colors[i] = colors;
  });
  return out;
}

// Mean colour coordinate of `sum` visits whose coordinates add up to `col`.
float MeanColor(uint64_t col, uint64_t sum) {
  return sum ? float(double(col) / (double(sum) * CountGrid::kColorScale)) : 0.f;
}

// One sample per pixel: a row's pixels straight from their tiles, 32
// columns (one tile) at a time, without the general filter's per-sample
// arithmetic; the same floats as the general path (a mean of one).
void CopyRow(const std::vector<PartTiles>& tiles, Int3 nt, int row, int width, float* density,
             float* color) {
  for (int x0 = 0; x0 < width; x0 += 32) {
    const size_t tile = (size_t(x0 >> 5) * size_t(nt.y) + size_t(row >> 10)) * size_t(nt.z);
    // The offset's fields are disjoint bits: adding the column's is or-ing it.
    const uint32_t base = CountGrid::LocalOffset(0, (row >> 5) & 31, row & 31);
    for (int i = 0; i < std::min(32, width - x0); ++i) {
      const uint32_t off = base + CountGrid::LocalOffset(i, 0, 0);
      uint64_t sum = 0, col = 0;
      for (const PartTiles& t : tiles) {
        if (const uint32_t* c = t.counts[tile]) sum += c[off];
        if (const uint64_t* c = t.colors[tile]) col += c[off];
      }
      density[x0 + i] = float(double(sum));
      color[x0 + i] = MeanColor(col, sum);
    }
  }
}

}  // namespace

absl::StatusOr<ImageDensity> BoxFilterImage(const std::vector<const CountGrid*>& parts,
                                            int samples_w, int samples_h, int factor, int taps,
                                            Interrupter* interrupter) {
  if (samples_w <= 0 || samples_h <= 0 || factor <= 0 || taps <= 0 || taps > factor)
    return absl::InvalidArgumentError("bad image filter size");
  for (const CountGrid* g : parts)
    if (g->resolution() != FoldedImageResolution(samples_w, samples_h))
      return absl::InvalidArgumentError("image counters do not match the image size");
  ImageDensity out;
  out.width = (samples_w + factor - 1) / factor;
  out.height = (samples_h + factor - 1) / factor;
  const size_t n = size_t(out.width) * size_t(out.height);
  out.density.resize(n);  // uncleared: every pixel is written below
  out.color.resize(n);
  std::vector<PartTiles> tiles;
  for (const CountGrid* g : parts) tiles.push_back(IndexTiles(*g));
  // Folded layout: sample (sx, sy) is voxel (sx, sy >> 5, sy & 31), whose
  // tile is (sx >> 5, sy >> 10, 0) (every part has the same resolution).
  const Int3 nt = parts.empty() ? Int3{1, 1, 1} : parts[0]->tiles();
  absl::Status st = ForRows(out.height, interrupter, [&](int row) {
    const size_t first = size_t(row) * size_t(out.width);
    if (factor == 1)
      return CopyRow(tiles, nt, row, out.width, &out.density[first], &out.color[first]);
    for (int x = 0; x < out.width; ++x) {
      uint64_t sum = 0, col = 0, used = 0;
      for (int j = 0; j < taps; ++j) {
        const int sy = row * factor + j * factor / taps;
        if (sy >= samples_h) break;
        for (int i = 0; i < taps; ++i) {
          const int sx = x * factor + i * factor / taps;
          if (sx >= samples_w) break;
          ++used;
          const Int3 v = FoldedImageVoxel(sx, sy);
          const size_t tile =
              (size_t(v.x >> 5) * size_t(nt.y) + size_t(v.y >> 5)) * size_t(nt.z);
          const uint32_t off = CountGrid::LocalOffset(v.x & 31, v.y & 31, v.z);
          for (const PartTiles& t : tiles) {
            if (const uint32_t* c = t.counts[tile]) sum += c[off];
            if (const uint64_t* c = t.colors[tile]) col += c[off];
          }
        }
      }
      const size_t p = size_t(row) * size_t(out.width) + size_t(x);
      out.density[p] = float(double(sum) / double(used));
      out.color[p] = MeanColor(col, sum);
    }
  });
  if (!st.ok()) return st;
  return out;
}

double ToneMap(const LookParams& look, double d, double dmin, double dmax) {
  if (!(d > 0) || !(dmax > 0)) return 0;
  double v = 0;
  switch (look.tone) {
    case ToneMapping::kSqrt: {
      const double lo = std::sqrt(dmin), hi = std::sqrt(dmax);
      // A picture whose lit pixels all have one density is lit uniformly.
      v = hi > lo ? (std::sqrt(d) - lo) / (hi - lo) : 1;
      break;
    }
    case ToneMapping::kLog:
      v = std::log1p(d) / std::log1p(dmax);
      break;
    case ToneMapping::kGamma:
      v = std::pow(d / dmax, 1 / look.gamma);
      break;
    case ToneMapping::kLinear:
      v = d / dmax;
      break;
  }
  return std::clamp(v, 0.0, 1.0);
}

Developer::Developer(const ImageDensity& image, const LookParams& look)
    : image_(image), look_(look) {
  for (float d : image.density) {
    if (!(d > 0)) continue;
    dmin_ = dmin_ > 0 ? std::min(dmin_, d) : d;
    dmax_ = std::max(dmax_, d);
  }
}

Vec3 Developer::Shade(Vec3 c, double v) const {
  // Mix with the colour's own grey (Rec. 709 luma) to desaturate.
  const double grey = 0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z;
  c = (1 - look_.desaturation) * c + look_.desaturation * Vec3{grey, grey, grey};
  return Vec3{c.x * v, c.y * v, c.z * v};
}

void Developer::Rows(int first, int last, float* rgb) const {
  for (int row = first; row < last; ++row)
    Row(row, rgb + 3 * size_t(row - first) * size_t(image_.width));
}

void Developer::Row(int row, float* rgb) const {
  const size_t first = size_t(row) * size_t(image_.width);
  std::vector<int> lit;
  std::vector<double> t, v;
  for (int x = 0; x < image_.width; ++x) {
    const double d = image_.density[first + size_t(x)];
    if (!(d > 0)) {
      for (int c = 0; c < 3; ++c) rgb[3 * x + c] = float(look_.background[c]);
      continue;
    }
    lit.push_back(x);
    v.push_back(look_.brightness * ToneMap(look_, d, dmin_, dmax_));
    t.push_back(look_.colored ? image_.color[first + size_t(x)] : 0.0);
  }
  // The palette's sines a batch at a time; a pixel whose floats could
  // round otherwise than Eval's colour would make them is redone with it.
  std::vector<Vec3> near(lit.size(), Vec3{1, 1, 1});
  if (look_.colored) look_.palette.EvalNear(t.data(), t.size(), near.data());
  // The colours are within 2^-50 of Eval's, so the mix within
  // (|1 - desaturation| + |desaturation|) 2^-49 and a value within v times
  // that plus its own rounding: the margin is 16 times as much.
  const double mix = std::fabs(1 - look_.desaturation) + std::fabs(look_.desaturation);
  for (size_t k = 0; k < lit.size(); ++k) {
    Vec3 y = Shade(near[k], v[k]);
    auto alike = [&](double c) {
      return palette_internal::RoundsAlike(c, (std::fabs(v[k]) * mix + std::fabs(c)) * 0x1.0p-44);
    };
    if (look_.colored && !(alike(y.x) && alike(y.y) && alike(y.z))) [[unlikely]]
      y = Shade(look_.palette.Eval(t[k]), v[k]);
    for (int c = 0; c < 3; ++c) rgb[3 * size_t(lit[k]) + size_t(c)] = float(y[c]);
  }
}

absl::StatusOr<RgbImage> DevelopImage(const ImageDensity& image, const LookParams& look,
                                      Interrupter* interrupter) {
  const Developer developer(image, look);
  RgbImage out;
  out.width = image.width;
  out.height = image.height;
  out.rgb.resize(3 * size_t(image.width) * size_t(image.height));  // every pixel is written
  NIMBUS_RETURN_IF_ERROR(ForRows(image.height, interrupter,
                                 [&](int row) { developer.Rows(row, row + 1, out.At(0, row)); }));
  AddGlow(out, look.glow, look.glow_radius);
  return out;
}

namespace {

// Widths of three box filters whose succession approximates a Gaussian of
// standard deviation `sigma` (the variances of the boxes add up to
// sigma^2): odd widths wl or wl + 2, the first `m` of them wl.
std::array<int, 3> BoxWidths(double sigma) {
  const double ideal = std::sqrt(12 * sigma * sigma / 3 + 1);
  int wl = int(std::floor(ideal));
  if (wl % 2 == 0) --wl;
  wl = std::max(wl, 1);
  const double m = std::round((12 * sigma * sigma - 3.0 * wl * wl - 12.0 * wl - 9) /
                              (-4.0 * wl - 4));
  std::array<int, 3> w{};
  for (int i = 0; i < 3; ++i) w[size_t(i)] = i < m ? wl : wl + 2;
  return w;
}

// One box filter of odd width `width` over the `n` values of `in` into
// `out`, edges extended; a running sum in double, so each output costs O(1)
// whatever the width.
void BoxPass(const float* in, float* out, int n, int width) {
  const int r = width / 2;
  auto at = [&](int i) { return double(in[std::clamp(i, 0, n - 1)]); };
  double sum = 0;
  for (int i = -r; i <= r; ++i) sum += at(i);
  const double inv = 1.0 / width;
  for (int i = 0; i < n; ++i) {
    out[i] = float(sum * inv);
    sum += at(i + r + 1) - at(i - r);
  }
}

// The three box filters of `widths` along a line of `n` values `stride`
// apart (one channel): gathered once into `a`, filtered between `a` and
// `b`, scattered back once.
void BoxLine(float* v, int n, size_t stride, const std::array<int, 3>& widths,
             std::vector<float>& a, std::vector<float>& b) {
  a.resize(size_t(n));
  b.resize(size_t(n));
  for (int i = 0; i < n; ++i) a[size_t(i)] = v[size_t(i) * stride];
  BoxPass(a.data(), b.data(), n, widths[0]);
  BoxPass(b.data(), a.data(), n, widths[1]);
  BoxPass(a.data(), b.data(), n, widths[2]);
  for (int i = 0; i < n; ++i) v[size_t(i) * stride] = b[size_t(i)];
}

}  // namespace

void AddGlow(RgbImage& image, double amount, double radius) {
  if (!HasGlow(amount, radius) || image.rgb.empty()) return;
  // A Gaussian approximated by three box filters per axis (rows, then
  // columns), each line filtered on its own: O(1) per pixel for any radius,
  // and the same result for any thread count.
  const std::array<int, 3> widths = BoxWidths(radius);
  const int W = image.width, H = image.height;
  PixelBuffer blur = image.rgb;
  tbb::parallel_for(0, H, [&](int y) {
    std::vector<float> a, b;
    for (int c = 0; c < 3; ++c) BoxLine(&blur[3 * size_t(y) * W + c], W, 3, widths, a, b);
  });
  // Columns in blocks of 16, copied out to a contiguous buffer so each
  // filter pass walks memory row by row instead of one cache line per value.
  constexpr int kBlock = 16;
  tbb::parallel_for(0, (W + kBlock - 1) / kBlock, [&](int blk) {
    const int x0 = blk * kBlock, n = std::min(kBlock, W - x0);
    const size_t row = 3 * size_t(n);
    std::vector<float> block(row * size_t(H)), a, b;
    for (int y = 0; y < H; ++y)
      std::copy_n(&blur[3 * (size_t(y) * W + x0)], row, &block[size_t(y) * row]);
    for (size_t k = 0; k < row; ++k) BoxLine(&block[k], H, row, widths, a, b);
    for (int y = 0; y < H; ++y)
      std::copy_n(&block[size_t(y) * row], row, &blur[3 * (size_t(y) * W + x0)]);
  });
  const float a = float(amount);
  tbb::parallel_for(0, H, [&](int y) {
    float* o = &image.rgb[3 * size_t(y) * W];
    const float* b = &blur[3 * size_t(y) * W];
    for (size_t i = 0; i < 3 * size_t(W); ++i) o[i] += a * b[i];
  });
}

}  // namespace nimbus
