// Picture throughput (docs/images.md): examples/poster.json (6000 x 9000,
// 2 x 2 supersampling, colour by address, arcs) counted into its picture,
// against the same walk counted into a plain grid, and the look's cost
// (box filter, tone mapping, palette, desaturation, glow, PNG write).
// The look's whole cost is also measured as the same picture with and
// without it: grey counts and a plain develop, against colour by address,
// palette, desaturation and glow. Also the 2D Sierpinski triangle of
// bench/compare_flam3.sh as a 1024^2 picture on the fast path, and the
// explorer's contact sheet of examples/explore.json (64 thumbnails of 256^2,
// docs/explore.md). Prints figures; asserts nothing.
//
// Usage: image_bench [ITERATIONS [THREADS [THUMBNAILS [SHEET.png]]]]
// (default 2^28, 2 and 64; the figures are 10^9 points and 64
// thumbnails; ITERATIONS 0 runs the contact sheet only; SHEET.png saves it)
#include <tbb/global_control.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>

#include "core/chaos/auto_frame.h"
#include "core/chaos/chaos_game.h"
#include "core/chaos/ifs_explorer.h"
#include "core/grid/contact_sheet.h"
#include "core/grid/image_look.h"
#include "core/io/image_io.h"
#include "proto/spec_convert.h"
#include "proto/spec_io.h"

namespace nimbus {
namespace {

using Clock = std::chrono::steady_clock;
double Since(Clock::time_point t) {
  return std::chrono::duration<double>(Clock::now() - t).count();
}

// Runs `p` and returns the seconds; keeps the counts in `out`.
double RunGame(const ChaosGameParams& p, int threads, CountGrid* out) {
  const auto t = Clock::now();
  auto game = ChaosGame::Create(p, threads);
  if (!game.ok()) {
    std::fprintf(stderr, "%s\n", std::string(game.status().message()).c_str());
    std::exit(1);
  }
  if (!(*game)->Run(nullptr).ok()) std::exit(1);
  CountGrid counts = (*game)->TakeCounts();
  const double s = Since(t);
  if (out) *out = std::move(counts);
  return s;
}

void Row(const char* what, uint64_t n, double s) {
  std::printf("%-52s %12llu %9.2f s %9.1f M/s\n", what, static_cast<unsigned long long>(n), s,
              double(n) / s / 1e6);
}

// examples/explore.json with `count` thumbnails: the explorer's contact
// sheet (drawing, testing, framing, counting, developing, composing).
int ContactSheetBench(int count, int threads, const char* save_to) {
  auto spec = spec::LoadSpecFile(std::string(NIMBUS_SOURCE_DIR) + "/examples/explore.json");
  if (!spec.ok()) return 1;
  spec->mutable_explore()->set_count(count);
  auto plan = spec::ConvertSpec(*spec, spec::Limits{});
  if (!plan.ok()) {
    std::fprintf(stderr, "%s\n", std::string(plan.status().message()).c_str());
    return 1;
  }
  const ExploreParams& p = plan->explore()->params;
  std::vector<RgbImage> thumbs;
  const auto t = Clock::now();
  auto stats = ExploreIfs(p, threads, nullptr, [&](const ExploreCandidate&, RgbImage im) {
    thumbs.push_back(std::move(im));
    return absl::OkStatus();
  });
  if (!stats.ok()) return 1;
  const double explore_s = Since(t);
  const auto t2 = Clock::now();
  auto sheet = ComposeContactSheet(
      thumbs, ContactSheetLayout(int(thumbs.size()), p.thumbnail_size, 0), {}, true);
  if (!sheet.ok() || !EncodePng8(*sheet).ok()) return 1;
  const double sheet_s = Since(t2);
  if (save_to && !WriteImage(save_to, *sheet, ImageFormat::kPng8).ok()) return 1;
  const double total = explore_s + sheet_s;
  std::printf("contact sheet: %zu thumbnails of %d^2 (%llu points each) in %.2f s, %.1f "
              "thumbnails/s\n  (%llu random IFS drawn, %llu contractive; compose + PNG %.3f s)\n",
              thumbs.size(), p.thumbnail_size,
              static_cast<unsigned long long>(p.thumbnail_iterations), total,
              double(thumbs.size()) / total, static_cast<unsigned long long>(stats->attempts),
              static_cast<unsigned long long>(stats->contractive), sheet_s);
  return 0;
}

int Main(int argc, char** argv) {
  const uint64_t iterations = argc > 1 ? std::strtoull(argv[1], nullptr, 10) : uint64_t{1} << 28;
  const int threads = argc > 2 ? std::atoi(argv[2]) : 2;
  const int thumbnails = argc > 3 ? std::atoi(argv[3]) : 64;
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism, size_t(threads));
  const char* save_to = argc > 4 ? argv[4] : nullptr;
  if (iterations == 0) return ContactSheetBench(thumbnails, threads, save_to);  // the sheet only
  auto spec = spec::LoadSpecFile(std::string(NIMBUS_SOURCE_DIR) + "/examples/poster.json");
  if (!spec.ok()) return 1;
  auto plan = spec::ConvertSpec(*spec, spec::Limits{});
  if (!plan.ok()) {
    std::fprintf(stderr, "%s\n", std::string(plan.status().message()).c_str());
    return 1;
  }
  const ChaosGamePlan& cg = *plan->chaos_game();
  const ImageJob& im = *cg.image;
  ChaosGameParams p = cg.params;
  p.iterations = iterations;
  std::printf("%-52s %12s %11s %13s\n", "run", "points", "wall", "rate");
  auto t = Clock::now();
  auto box = FitBounds(p, *cg.auto_frame, nullptr);
  if (!box.ok()) return 1;
  p.frame.bounds = *box;
  std::printf("%-52s %12llu %9.3f s\n", "auto-frame pilot",
              static_cast<unsigned long long>(cg.auto_frame->pilot_iterations), Since(t));

  // The same walk into a plain grid: the iteration rate without a picture.
  ChaosGameParams plain = p;
  plain.frame.resolution = {1024, 1536, 1};
  Row("poster walk into a 1024x1536x1 grid (colour)", iterations, RunGame(plain, threads, nullptr));

  const int ss = im.supersample;
  ChaosGameParams pic = p;
  pic.image = MakeImagePlane(im.view, p.frame.bounds, im.width * ss, im.height * ss);
  CountGrid counts({1, 1, 1});
  const double walk_s = RunGame(pic, threads, &counts);
  Row("poster picture 12000x18000 samples (colour)", iterations, walk_s);

  t = Clock::now();
  auto density = BoxFilterImage({&counts}, pic.image->width, pic.image->height, ss, ss, nullptr);
  counts = CountGrid({1, 1, 1});
  const double filter_s = Since(t);
  LookParams look = im.look;
  look.glow_radius = 0.01 * std::max(im.width, im.height);
  t = Clock::now();
  auto rgb = DevelopImage(*density, look, nullptr);
  const double develop_s = Since(t);
  const std::filesystem::path out = std::filesystem::temp_directory_path() / "image_bench.png";
  t = Clock::now();
  if (!WriteImage(out, *rgb, ImageFormat::kPng8).ok()) return 1;
  const double png_s = Since(t);
  const double look_s = filter_s + develop_s;
  std::printf("%-52s %25.2f s\n", "box filter 2x2 -> 6000x9000", filter_s);
  std::printf("%-52s %25.2f s\n", "tone map, palette, desaturation, glow", develop_s);
  std::printf("%-52s %25.2f s  (%.0f MB)\n", "PNG write (8-bit)", png_s,
              double(std::filesystem::file_size(out)) / 1e6);
  std::printf("look (filter + develop) = %.1f %% of the walk's %.2f s; poster total %.2f s\n",
              100 * look_s / walk_s, walk_s, walk_s + look_s + png_s);
  std::filesystem::remove(out);
  *rgb = RgbImage{};
  *density = ImageDensity{};

  // The same picture without the look: grey counts (no colour per sample),
  // then a develop with no palette, desaturation or glow.
  ChaosGameParams grey = pic;
  grey.color = {};
  const double grey_walk_s = RunGame(grey, threads, &counts);
  Row("poster picture without the look (grey)", iterations, grey_walk_s);
  t = Clock::now();
  auto grey_density =
      BoxFilterImage({&counts}, grey.image->width, grey.image->height, ss, ss, nullptr);
  counts = CountGrid({1, 1, 1});
  LookParams plain_look;
  plain_look.colored = false;
  auto grey_rgb = DevelopImage(*grey_density, plain_look, nullptr);
  const double grey_look_s = Since(t);
  const double with = walk_s + look_s, without = grey_walk_s + grey_look_s;
  std::printf("%-52s %25.2f s\n", "plain filter + develop (grey, no glow)", grey_look_s);
  std::printf("poster with the look %.2f s (%.1f M points/s), without %.2f s (%.1f M points/s):"
              " the look costs %.1f %%\n",
              with, double(iterations) / with / 1e6, without,
              double(iterations) / without / 1e6, 100 * (with - without) / without);

  // The flam3 comparison's Sierpinski triangle, drawn as a 1024^2 picture:
  // affine, no colour, so the fast path walks in pixel space.
  ChaosGameParams tri;
  for (Vec3 o : {Vec3{0, 0, 0}, Vec3{0.5, 0, 0}, Vec3{0.25, 0.5, 0}}) {
    PointMap m;
    m.pre = Affine3::Translate(o) * Affine3::Scale({0.5, 0.5, 0});
    tri.ifs.maps.push_back(m);
    tri.ifs.probabilities.push_back(1.0 / 3);
  }
  tri.frame = {{1024, 1024, 1}, {{-0.1, -0.1, -0.5}, {1.1, 1.1, 0.5}}};
  tri.iterations = iterations;
  tri.seed = 1;
  Row("sierpinski 2D into a 1024^2 grid (fast path)", iterations, RunGame(tri, threads, nullptr));
  tri.image = MakeImagePlane(ImageView{}, tri.frame.bounds, 1024, 1024);
  Row("sierpinski 2D 1024^2 picture (fast path)", iterations, RunGame(tri, threads, nullptr));
  tri.color.mode = ColorMode::kAddress;
  Row("sierpinski 2D 1024^2 picture, colour (general path)", iterations,
      RunGame(tri, threads, nullptr));
  std::printf("(%d threads; flam3-render side by side: bench/compare_flam3.sh)\n", threads);
  return thumbnails > 0 ? ContactSheetBench(thumbnails, threads, save_to) : 0;
}

}  // namespace
}  // namespace nimbus

int main(int argc, char** argv) { return nimbus::Main(argc, argv); }
