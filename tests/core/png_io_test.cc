// PNG files through libpng (core/io/png_io.h): the samples given are the
// pixels libpng reads back, for every layout, size and content; the same
// bytes for any thread count; errors that stop it cleanly and leave no file.
#include "core/io/png_io.h"

#include <gtest/gtest.h>
#include <tbb/task_arena.h>

#include <cstdio>
#include <random>
#include <string>
#include <vector>

#include "core/grid/image_look.h"
#include "core/io/image_io.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

enum class Content { kRandom, kSmooth, kFlat, kSparse, kSteps };

// Samples whose rows favour different filters: noise (none), ramps (sub,
// up, average, Paeth), zeros (ties everywhere), a few bright dots on
// black like a flame's, and vertical bands (up).
std::vector<uint8_t> MakeSamples(const PngShape& s, Content c, uint32_t seed) {
  std::mt19937 rng(seed);
  std::vector<uint8_t> out(s.RowBytes() * size_t(s.height));
  const size_t row = s.RowBytes();
  for (size_t i = 0; i < out.size(); ++i) {
    const size_t x = i % row, y = i / row;
    switch (c) {
      case Content::kRandom:
        out[i] = uint8_t(rng());
        break;
      case Content::kSmooth:
        out[i] = uint8_t(3 * x + 5 * y + (rng() % 3));
        break;
      case Content::kFlat:
        out[i] = 0;
        break;
      case Content::kSparse:
        out[i] = rng() % 97 == 0 ? uint8_t(rng()) : 0;
        break;
      case Content::kSteps:
        out[i] = uint8_t((x / 7) * 40 + (y % 5 == 0 ? 1 : 0));
        break;
    }
  }
  return out;
}

PngRows RowsOf(const std::vector<uint8_t>& samples, const PngShape& s) {
  return [&samples, s](int first, int last, uint8_t* out) {
    std::copy(samples.begin() + ptrdiff_t(size_t(first) * s.RowBytes()),
              samples.begin() + ptrdiff_t(size_t(last) * s.RowBytes()), out);
    return absl::OkStatus();
  };
}

std::string Encode(const PngShape& s, const std::vector<uint8_t>& samples, int threads) {
  std::string out;
  tbb::task_arena arena(threads);
  arena.execute([&] {
    const absl::Status st = WritePng(s, RowsOf(samples, s), {nullptr, &out});
    EXPECT_TRUE(st.ok()) << st;
  });
  return out;
}

// The host-order samples of a PNG file as libpng reads them back.
std::vector<uint8_t> ReadBack(const std::filesystem::path& path) {
  auto png = ReadPngPixels(path);
  EXPECT_TRUE(png.ok()) << png.status();
  if (!png.ok()) return {};
  const size_t bytes = size_t(png->bit_depth / 8);
  std::vector<uint8_t> out(png->samples.size() * bytes);
  for (size_t i = 0; i < png->samples.size(); ++i)
    for (size_t b = 0; b < bytes; ++b) out[i * bytes + b] = uint8_t(png->samples[i] >> (8 * b));
  return out;
}

// Every layout at sizes from one pixel to several bands of rows.
TEST(PngWriter, LibpngReadsBackTheSamplesForEveryLayoutSizeAndContent) {
  const std::vector<std::pair<int, int>> sizes = {{1, 1},   {1, 9},   {9, 1},     {2, 2},
                                                  {37, 23}, {300, 7}, {700, 130}, {64, 600}};
  const testing::TempDir dir;
  uint32_t seed = 1;
  for (auto [w, h] : sizes)
    for (int depth : {8, 16})
      for (int channels : {1, 3})
        for (Content c : {Content::kRandom, Content::kSmooth, Content::kFlat, Content::kSparse,
                          Content::kSteps}) {
          const PngShape s{w, h, depth, channels};
          const std::vector<uint8_t> samples = MakeSamples(s, c, seed++);
          ASSERT_TRUE(WritePngFile(dir / "p.png", s, RowsOf(samples, s)).ok());
          ASSERT_EQ(ReadBack(dir / "p.png"), samples)
              << w << " x " << h << ", " << depth << " bits, " << channels << " channels, content "
              << int(c);
        }
}

// Rows are made on any thread and handed to libpng in order, so the bytes
// do not depend on how many threads made them.
TEST(PngWriter, SameBytesForAnyThreadCount) {
  const PngShape s{1500, 300, 8, 3};
  const std::vector<uint8_t> samples = MakeSamples(s, Content::kSparse, 42);
  const std::string one = Encode(s, samples, 1);
  ASSERT_FALSE(one.empty());
  for (int threads : {2, 3, 8}) EXPECT_EQ(Encode(s, samples, threads), one) << threads;
}

TEST(PngWriter, RefusesShapesPngCannotHoldNamingThem) {
  std::string out;
  const std::vector<uint8_t> none;
  for (const PngShape& s : {PngShape{0, 5, 8, 3}, PngShape{5, -1, 8, 3}}) {
    const absl::Status st = WritePng(s, RowsOf(none, s), {nullptr, &out});
    EXPECT_TRUE(absl::IsInvalidArgument(st)) << st;
    EXPECT_NE(st.message().find("no valid size"), std::string::npos) << st;
  }
  const PngShape odd{4, 4, 12, 3};
  const absl::Status st = WritePng(odd, RowsOf(none, odd), {nullptr, &out});
  EXPECT_TRUE(absl::IsInvalidArgument(st)) << st;
  EXPECT_NE(st.message().find("12 bits"), std::string::npos) << st;
  EXPECT_TRUE(out.empty());
}

// A band that cannot be made stops the writer with that band's error.
TEST(PngWriter, AFailingRowSourceStopsWithItsError) {
  const PngShape s{100, 4000, 8, 3};
  auto rows = [&](int first, int last, uint8_t* out) {
    std::fill_n(out, size_t(last - first) * s.RowBytes(), uint8_t(7));
    if (last > 2000) return absl::DataLossError("row 2000 is missing");
    return absl::OkStatus();
  };
  std::string out;
  const absl::Status st = WritePng(s, rows, {nullptr, &out});
  EXPECT_TRUE(absl::IsDataLoss(st)) << st;
  EXPECT_EQ(st.message(), "row 2000 is missing");
}

TEST(PngWriter, AFullDiskIsResourceExhausted) {
  FILE* full = std::fopen("/dev/full", "wb");
  ASSERT_NE(full, nullptr);
  std::setvbuf(full, nullptr, _IONBF, 0);  // each chunk reaches the device
  const PngShape s{64, 64, 8, 1};
  const std::vector<uint8_t> samples = MakeSamples(s, Content::kRandom, 3);
  const absl::Status st = WritePng(s, RowsOf(samples, s), {full, nullptr});
  std::fclose(full);
  EXPECT_TRUE(absl::IsResourceExhausted(st)) << st;
  EXPECT_NE(st.message().find("write failed"), std::string::npos) << st;
}

// Cancelling a picture being written leaves no file, partial or final.
TEST(PngWriter, CancellingLeavesNoFile) {
  ImageDensity d;
  d.width = 300;
  d.height = 2000;
  d.density.assign(size_t(d.width) * size_t(d.height), 1.f);
  d.color.assign(d.density.size(), 0.5f);
  const testing::TempDir dir;
  testing::CancelAfter stop(3);
  const absl::Status st =
      WriteDevelopedImage(dir / "p.png", d, LookParams{}, ImageFormat::kPng8, &stop);
  EXPECT_TRUE(absl::IsCancelled(st)) << st;
  EXPECT_TRUE(std::filesystem::is_empty(dir.path()));
}

// Developing band by band while libpng encodes gives the file that developing
// the whole picture and then writing it gives, for both PNG depths; with
// glow (which needs the whole picture) and for EXR it is that path.
TEST(PngWriter, StreamedDevelopmentWritesTheWholePicturesFile) {
  ImageDensity d;
  d.width = 333;
  d.height = 517;
  std::mt19937 rng(5);
  for (int i = 0; i < d.width * d.height; ++i) {
    const bool lit = rng() % 3 == 0;
    d.density.push_back(lit ? float(1 + rng() % 5000) : 0.f);
    d.color.push_back(lit ? float(rng() % 1000) / 1000.f : 0.f);
  }
  LookParams plain, glow;
  glow.glow = 0.5;
  glow.glow_radius = 4;
  const testing::TempDir dir;
  for (const LookParams& look : {plain, glow})
    for (ImageFormat f : {ImageFormat::kPng8, ImageFormat::kPng16, ImageFormat::kExr}) {
      const std::string ext = ImageExtension(f);
      auto whole = DevelopImage(d, look, nullptr);
      ASSERT_TRUE(whole.ok());
      ASSERT_TRUE(WriteImage(dir / ("a" + ext), *whole, f).ok());
      ASSERT_TRUE(WriteDevelopedImage(dir / ("b" + ext), d, look, f, nullptr).ok());
      const std::string a = testing::ReadFileBytes(dir / ("a" + ext));
      EXPECT_FALSE(a.empty());
      EXPECT_EQ(a, testing::ReadFileBytes(dir / ("b" + ext))) << ext << " glow " << look.glow;
    }
}

}  // namespace
}  // namespace nimbus
