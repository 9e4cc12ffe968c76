// Runs explore jobs (docs/explore.md): random IFS drawn from the seed,
// thumbnails of the kept ones on a contact sheet (the main result, a PNG)
// and one spec per candidate as further files NAME.0001.json, ... in sheet
// order.
#include <cstdio>
#include <fstream>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/base/status_macros.h"
#include "core/chaos/ifs_explorer.h"
#include "core/grid/contact_sheet.h"
#include "core/io/image_io.h"
#include "proto/explore_candidate.h"
#include "proto/spec_io.h"
#include "server/job_driver.h"

namespace nimbus::server {

namespace {

// The sheet's colour between thumbnails: dark, so the labels' boxes and the
// thumbnails' black backgrounds stay apart.
constexpr Vec3 kSheetBackground{0.18, 0.18, 0.2};

// "NAME.0007.json" for candidate 6 (0-based).
std::string CandidateFileName(const std::string& name, size_t index) {
  return absl::StrFormat("%s.%04d.json", name, index + 1);
}

// Writes `text` beside the scratch result, then renames it into `path`, so
// a listing never shows half a file.
absl::Status WriteTextFile(const std::filesystem::path& scratch_dir,
                           const std::filesystem::path& path, const std::string& text) {
  const std::filesystem::path tmp = scratch_dir / (path.filename().string() + ".tmp");
  {
    std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
    out.write(text.data(), std::streamsize(text.size()));
    if (!out.flush()) return absl::InternalError(absl::StrCat("cannot write ", tmp.string()));
  }
  std::error_code ec;
  std::filesystem::rename(tmp, path, ec);
  if (ec) return absl::InternalError(absl::StrCat("cannot write ", path.string(), ": ",
                                                  ec.message()));
  return absl::OkStatus();
}

}  // namespace

absl::Status RunKind(const JobPlan& plan, const ExplorePlan& kind, JobContext& ctx) {
  JobDriver d(plan, ctx);
  NIMBUS_RETURN_IF_ERROR(d.BeginPhase(JobPhase::kIterating, plan.work.total, plan.work.unit));
  ExploreParams params = kind.params;
  params.memory_budget = ctx.memory_budget();
  std::vector<ExploreCandidate> kept;
  std::vector<RgbImage> thumbs;
  auto stats = ExploreIfs(params, ctx.threads(), d.interrupter(),
                          [&](const ExploreCandidate& c, RgbImage thumb) {
                            kept.push_back(c);
                            thumbs.push_back(std::move(thumb));
                            return d.Progress(kept.size());
                          });
  NIMBUS_RETURN_IF_ERROR(d.Check(stats.status()));
  NIMBUS_RETURN_IF_ERROR(d.Progress(kept.size(), true));
  ctx.SetStat("explore_attempts", stats->attempts);
  ctx.SetStat("explore_contractive", stats->contractive);
  ctx.SetStat("explore_kept", stats->kept);
  if (kept.empty())
    return absl::FailedPreconditionError(absl::StrCat(
        "explore: no candidate kept in ", stats->attempts, " random IFS (", stats->contractive,
        " passed the contraction test); raise explore.threshold or explore.max_attempts, or "
        "lower explore.min_coverage"));
  if (kept.size() < size_t(params.count))
    ctx.AddWarning(absl::StrCat("explore: kept ", kept.size(), " of ", params.count,
                                " candidates in ", stats->attempts,
                                " random IFS (explore.max_attempts)"));
  NIMBUS_RETURN_IF_ERROR(d.BeginPhase(JobPhase::kWriting, kept.size() + 1, "files"));
  const std::filesystem::path scratch = ctx.ResultScratchPath();
  for (size_t i = 0; i < kept.size(); ++i) {
    const std::string file = CandidateFileName(plan.name, i);
    NIMBUS_ASSIGN_OR_RETURN(
        v1::JobSpec spec,
        spec::ExploreCandidateSpec(kind.candidate_template, kept[i],
                                   absl::StrFormat("%s_%04d", plan.name, i + 1)));
    NIMBUS_ASSIGN_OR_RETURN(std::filesystem::path path, d.ExtraFilePath(file));
    NIMBUS_RETURN_IF_ERROR(WriteTextFile(scratch.parent_path(), path, spec::SpecToJson(spec)));
    NIMBUS_RETURN_IF_ERROR(d.Progress(i + 1));
  }
  const SheetLayout layout = ContactSheetLayout(int(kept.size()), params.thumbnail_size,
                                                kind.columns);
  NIMBUS_ASSIGN_OR_RETURN(RgbImage sheet,
                          ComposeContactSheet(thumbs, layout, kSheetBackground, true));
  thumbs.clear();
  NIMBUS_RETURN_IF_ERROR(WriteImage(scratch, sheet, ImageFormat::kPng8));
  ctx.SetStat("image_width", uint64_t(sheet.width));
  ctx.SetStat("image_height", uint64_t(sheet.height));
  return d.Progress(kept.size() + 1, true);
}

}  // namespace nimbus::server
