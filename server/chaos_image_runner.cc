// Runs chaos games with grid.auto_frame or a picture (docs/images.md): fits
// the box to the attractor from a pilot, counts the picture straight into
// its supersampled pixels, develops and writes it, then the volume unless
// the spec asked for the picture only.
#include <algorithm>

#include "absl/strings/str_cat.h"
#include "core/base/status_macros.h"
#include "core/chaos/auto_frame.h"
#include "core/chaos/chaos_game.h"
#include "core/grid/image_look.h"
#include "core/io/image_io.h"
#include "server/chaos_runs.h"
#include "server/job_driver.h"

namespace nimbus::server {

namespace {

// Samples read per axis per preview pixel: previews stay cheap for any
// picture size (a 12000 x 18000 poster's preview reads ~1 M counters).
constexpr int kPreviewTaps = 4;

int CeilDiv(int a, int b) { return (a + b - 1) / b; }

// The look at another picture size: the glow's radius is in output pixels.
LookParams ScaledLook(LookParams look, double scale) {
  look.glow_radius *= scale;
  return look;
}

// A watcher's preview of the picture so far: a PNG of at most
// `preview_size` pixels on its longest side and a 2D density grid of at
// most `resolution` voxels per axis (x = column, y = row up from the
// bottom, one voxel deep, in a box whose longest side is 1).
absl::StatusOr<JobContext::PicturePreview> MakePreview(
    const std::vector<const CountGrid*>& parts, const ImagePlane& plane, const ImageJob& im,
    const LookParams& look, int resolution) {
  const int longest = std::max(plane.width, plane.height);
  JobContext::PicturePreview out;
  const int f = CeilDiv(longest, im.preview_size);
  NIMBUS_ASSIGN_OR_RETURN(ImageDensity small, BoxFilterImage(parts, plane.width, plane.height, f,
                                                             std::min(f, kPreviewTaps), nullptr));
  const double scale = double(small.width) / double(im.width);
  NIMBUS_ASSIGN_OR_RETURN(RgbImage rgb, DevelopImage(small, ScaledLook(look, scale), nullptr));
  NIMBUS_ASSIGN_OR_RETURN(out.png, EncodePng8(rgb));
  const int g = CeilDiv(longest, std::max(1, resolution));
  const int taps = std::min(g, kPreviewTaps);
  NIMBUS_ASSIGN_OR_RETURN(ImageDensity grid,
                          BoxFilterImage(parts, plane.width, plane.height, g, taps, nullptr));
  out.counts = CountGrid({grid.width, grid.height, 1});
  for (int row = 0; row < grid.height; ++row)
    for (int x = 0; x < grid.width; ++x) {
      // Mean visits per sample, in 1/1024ths so thin previews keep detail.
      const double d = grid.density[size_t(row) * size_t(grid.width) + size_t(x)];
      const uint32_t n = uint32_t(std::min(d * 1024.0, 4e9));
      if (n) out.counts.Add(x, grid.height - 1 - row, 0, n);
    }
  const double unit = 1.0 / double(std::max(grid.width, grid.height));
  out.frame.resolution = {grid.width, grid.height, 1};
  out.frame.bounds = {{0, 0, 0}, {grid.width * unit, grid.height * unit, unit}};
  return out;
}

// Counts the picture, develops it and writes it to `path`.
absl::Status RunPicturePass(JobDriver& d, ChaosGameParams params, const ImageJob& im,
                            JobContext& ctx, const std::filesystem::path& path) {
  const int height =
      im.height > 0 ? im.height : DefaultImageHeight(im.view, params.frame.bounds, im.width);
  const int ss = im.supersample;
  const int64_t samples = int64_t(im.width) * height * ss * ss;
  if (samples > (int64_t{1} << 30))
    return absl::ResourceExhaustedError(
        absl::StrCat("image: the framed picture is ", im.width, " x ", height, " pixels with ", ss,
               " x ", ss, " supersampling, over the limit of 2^30 samples; set image.height"));
  params.image = MakeImagePlane(im.view, params.frame.bounds, im.width * ss, height * ss);
  params.memory_budget = ctx.memory_budget();
  NIMBUS_ASSIGN_OR_RETURN(auto game, ChaosGame::Create(std::move(params), ctx.threads()));
  const ImagePlane& plane = *game->params().image;
  LookParams look = im.look;
  if (im.default_glow_radius) look.glow_radius = 0.01 * std::max(im.width, height);
  JobDriver::Rounds rounds = ChaosRounds(*game, d, 0, {}, nullptr);
  rounds.preview = [&](uint64_t done) {
    ctx.MaybePublishPicturePreview(
        [&](int resolution) {
          std::vector<const CountGrid*> parts;
          for (const CountGrid& g : game->partial_counts()) parts.push_back(&g);
          return MakePreview(parts, plane, im, look, resolution);
        },
        done);
  };
  NIMBUS_RETURN_IF_ERROR(d.RunRounds(rounds));
  const ChaosGameStats stats = game->stats();
  ctx.SetStat("image_outside", stats.outside);
  ctx.SetStat("image_width", uint64_t(im.width));
  ctx.SetStat("image_height", uint64_t(height));
  if (stats.iterations_done > 0 && stats.outside * 2 > stats.iterations_done)
    ctx.AddWarning(absl::StrCat(stats.outside, " of ", stats.iterations_done,
                          " points fell outside the picture (try grid.auto_frame)"));
  ImageDensity density;
  {
    const CountGrid counts = game->TakeCounts();
    game.reset();
    NIMBUS_ASSIGN_OR_RETURN(density, BoxFilterImage({&counts}, plane.width, plane.height, ss, ss,
                                                    d.interrupter()));
  }
  return WriteDevelopedImage(path, density, look, im.format, d.interrupter());
}

}  // namespace

absl::Status RunChaosPicture(const JobPlan& in, const ChaosGamePlan& kind, JobContext& ctx) {
  JobPlan plan = in;  // with the fitted box, for the volume's transform
  ChaosGameParams params = kind.params;
  if (kind.auto_frame) {
    NIMBUS_ASSIGN_OR_RETURN(Bounds box, FitBounds(params, *kind.auto_frame, ctx.interrupter()));
    plan.frame.bounds = params.frame.bounds = box;
  }
  JobDriver d(plan, ctx);
  NIMBUS_RETURN_IF_ERROR(d.BeginPhase(JobPhase::kIterating, plan.work.total, plan.work.unit));
  if (!kind.image) return RunChaosVolume(d, std::move(params), 0, ctx);
  const ImageJob& im = *kind.image;
  if (im.image_only) {
    NIMBUS_RETURN_IF_ERROR(RunPicturePass(d, params, im, ctx, ctx.ResultScratchPath()));
    NIMBUS_RETURN_IF_ERROR(d.BeginPhase(JobPhase::kWriting, 1, "files"));
    return d.Progress(1, true);
  }
  NIMBUS_ASSIGN_OR_RETURN(std::filesystem::path path,
                          d.ExtraFilePath(plan.name + ImageExtension(im.format)));
  NIMBUS_RETURN_IF_ERROR(RunPicturePass(d, params, im, ctx, path));
  const uint64_t offset = params.iterations;
  return RunChaosVolume(d, std::move(params), offset, ctx);
}

}  // namespace nimbus::server
