// PNG writing (docs/images.md): the flam3 comparison's flame picture
// (bench/flam3/flame6_2d_image.json, 10^8 points at 1024^2) is drawn once,
// then written through libpng (WritePng) on one and on all threads, and as
// the picture job writes it: developed whole then written, and developed in
// bands while libpng encodes (WriteDevelopedImage), which must give the
// same bytes; the bench says so. Prints figures, best of REPEAT; asserts
// nothing.
//
// Usage: png_bench [THREADS [REPEAT]]   (default 2 and 7)
#include <tbb/global_control.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <functional>

#include "core/chaos/chaos_game.h"
#include "core/grid/image_look.h"
#include "core/io/image_io.h"
#include "core/io/png_io.h"
#include "proto/spec_convert.h"
#include "proto/spec_io.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

using Clock = std::chrono::steady_clock;

// Best wall time of `repeat` runs of `f`, in milliseconds.
double BestMs(int repeat, const std::function<void()>& f) {
  double best = 1e30;
  for (int i = 0; i < repeat; ++i) {
    const auto t = Clock::now();
    f();
    best = std::min(best, std::chrono::duration<double, std::milli>(Clock::now() - t).count());
  }
  return best;
}

// The flame picture's counters and look, as the picture job has them
// after its walk.
bool DrawFlame(CountGrid* counts, LookParams* look) {
  auto spec = spec::LoadSpecFile(testing::SourcePath("bench/flam3/flame6_2d_image.json").string());
  if (!spec.ok()) return false;
  auto plan = spec::ConvertSpec(*spec, spec::Limits{});
  if (!plan.ok() || plan->chaos_game() == nullptr) return false;
  const ChaosGamePlan& cg = *plan->chaos_game();
  ChaosGameParams p = cg.params;
  p.image = MakeImagePlane(cg.image->view, p.frame.bounds, cg.image->width, cg.image->width);
  auto game = ChaosGame::Create(p, tbb::this_task_arena::max_concurrency());
  if (!game.ok() || !(*game)->Run(nullptr).ok()) return false;
  *counts = (*game)->TakeCounts();
  *look = cg.image->look;
  return true;
}

// Quantised 8- or 16-bit samples of `rgb`, host order (std::lround).
std::vector<uint8_t> Samples(const RgbImage& rgb, int depth) {
  const double max = depth == 8 ? 255 : 65535;
  const size_t bytes = size_t(depth / 8);
  std::vector<uint8_t> out(rgb.rgb.size() * bytes);
  for (size_t i = 0; i < rgb.rgb.size(); ++i) {
    const float x = rgb.rgb[i];
    const long q = std::lround((x >= 0 ? std::min(double(x), 1.0) : 0.0) * max);
    for (size_t b = 0; b < bytes; ++b) out[i * bytes + b] = uint8_t(q >> (8 * b));
  }
  return out;
}

void Line(const char* what, double ms, const char* note = "") {
  std::printf("%-58s %8.1f ms %s\n", what, ms, note);
}

int Main(int argc, char** argv) {
  const int threads = argc > 1 ? std::atoi(argv[1]) : 2;
  const int repeat = argc > 2 ? std::atoi(argv[2]) : 7;
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism, size_t(threads));
  CountGrid counts({1, 1, 1});
  LookParams look;
  if (!DrawFlame(&counts, &look)) {
    std::fprintf(stderr, "png_bench: cannot draw bench/flam3/flame6_2d_image.json\n");
    return 1;
  }
  const int side = counts.resolution().x;
  absl::StatusOr<ImageDensity> filtered;
  const double box_ms =
      BestMs(repeat, [&] { filtered = BoxFilterImage({&counts}, side, side, 1, 1, nullptr); });
  if (!filtered.ok()) return 1;
  const ImageDensity& density = *filtered;
  auto rgb = DevelopImage(density, look, nullptr);
  if (!rgb.ok()) return 1;
  const testing::TempDir dir;
  std::printf("flame picture %d x %d, 8-bit RGB, %d threads\n", density.width, density.height,
              threads);
  for (int depth : {8, 16}) {
    const PngShape shape{density.width, density.height, depth, 3};
    const std::vector<uint8_t> samples = Samples(*rgb, depth);
    std::string bytes;
    auto rows = [&](int first, int last, uint8_t* out) {
      std::copy_n(&samples[size_t(first) * shape.RowBytes()],
                  size_t(last - first) * shape.RowBytes(), out);
      return absl::OkStatus();
    };
    std::printf("-- %d-bit samples\n", depth);
    Line("WritePng (libpng), 1 thread", BestMs(repeat, [&] {
           tbb::task_arena one(1);
           one.execute([&] {
             bytes.clear();
             (void)WritePng(shape, rows, {nullptr, &bytes});
           });
         }));
    Line("WritePng (libpng)", BestMs(repeat, [&] {
           bytes.clear();
           (void)WritePng(shape, rows, {nullptr, &bytes});
         }));
    std::printf("   %zu bytes\n", bytes.size());
  }
  const ImageFormat png8 = ImageFormat::kPng8;
  std::printf("-- the picture job's last step: box filter, develop and write the 8-bit PNG\n");
  Line("box filter, 1 sample per pixel", box_ms);
  Line("develop the whole picture, then WriteImage", BestMs(repeat, [&] {
         auto whole = DevelopImage(density, look, nullptr);
         (void)WriteImage(dir / "c.png", *whole, png8);
       }));
  Line("develop the whole picture alone",
       BestMs(repeat, [&] { (void)DevelopImage(density, look, nullptr); }));
  Line("WriteDevelopedImage (the job now)", BestMs(repeat, [&] {
         (void)WriteDevelopedImage(dir / "a.png", density, look, png8, nullptr);
       }));
  (void)WriteImage(dir / "b.png", *rgb, png8);
  const bool same = testing::ReadFileBytes(dir / "a.png") == testing::ReadFileBytes(dir / "b.png");
  std::printf("streamed and whole-picture files %s\n", same ? "are identical" : "DIFFER");
  return 0;
}

}  // namespace
}  // namespace nimbus

int main(int argc, char** argv) { return nimbus::Main(argc, argv); }
