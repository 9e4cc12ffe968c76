// Converts JobSpec.image (the picture: projection, size, format, look) and
// grid.auto_frame. Every range is checked here, before anything is
// allocated, and errors name the field.
#include <cmath>

#include "proto/convert_internal.h"

namespace nimbus::spec::internal {

namespace {

// Most samples (supersampling included) of one picture: the poster's
// 12000 x 18000 fits with room to spare.
constexpr int64_t kMaxImageSamples = int64_t{1} << 30;
constexpr int kMaxImageSide = 65536;
constexpr int kMaxSupersample = 8;

// `value` (0: unset, meaning `def`) must lie in [lo, hi].
absl::StatusOr<double> InRangeOr(double value, double def, double lo, double hi,
                                 const std::string& path) {
  NIMBUS_RETURN_IF_ERROR(CheckNumber(value, path));
  if (value == 0) return def;
  if (!(value >= lo && value <= hi))
    return Invalid(path, StrCat("must be in [", lo, ", ", hi, "], got ", value));
  return value;
}

absl::Status ConvertCamera(const v1::Camera& c, ImageView& view) {
  const std::string path = "image.camera";
  view.camera = true;
  switch (c.kind()) {
    case v1::CAMERA_KIND_UNSPECIFIED:
    case v1::CAMERA_KIND_ORTHOGRAPHIC: view.perspective = false; break;
    case v1::CAMERA_KIND_PERSPECTIVE: view.perspective = true; break;
    default: return Invalid(path + ".kind", StrCat("unknown value ", int(c.kind())));
  }
  for (auto [v, name] : {std::pair{&c.position(), "position"}, std::pair{&c.look_at(), "look_at"},
                         std::pair{&c.up(), "up"}})
    if (!Finite(*v)) return Invalid(StrCat(path, ".", name), "must be finite and within ±1e12");
  view.position = ToVec3(c.position());
  view.look_at = ToVec3(c.look_at());
  if (c.has_up()) view.up = ToVec3(c.up());
  const Vec3 f = view.look_at - view.position;
  if (!(Length(f) > 0)) return Invalid(path + ".look_at", "must differ from image.camera.position");
  if (!(Length(Cross(f, view.up)) > 1e-9 * Length(f) * Length(view.up)))
    return Invalid(path + ".up", "must not be zero or parallel to the view direction");
  if (view.perspective) {
    NIMBUS_ASSIGN_OR_RETURN(view.fov_degrees, InRangeOr(c.fov(), 40, 1e-3, 170, path + ".fov"));
  } else if (c.fov() != 0) {
    return Invalid(path + ".fov", "applies to CAMERA_KIND_PERSPECTIVE only (use ortho_height)");
  }
  NIMBUS_RETURN_IF_ERROR(CheckNumber(c.ortho_height(), path + ".ortho_height"));
  if (c.ortho_height() < 0) return Invalid(path + ".ortho_height", "must be >= 0");
  view.ortho_height = c.ortho_height();
  return absl::OkStatus();
}

absl::Status ConvertView(const v1::ImageOutput& im, ImageView& view) {
  if (im.has_camera()) {
    if (im.axis() != v1::PROJECTION_AXIS_UNSPECIFIED)
      return Invalid("image.axis", "set at most one of image.axis and image.camera");
    return ConvertCamera(im.camera(), view);
  }
  switch (im.axis()) {
    case v1::PROJECTION_AXIS_X: view.axis = ImageView::Axis::kX; break;
    case v1::PROJECTION_AXIS_Y: view.axis = ImageView::Axis::kY; break;
    case v1::PROJECTION_AXIS_UNSPECIFIED:
    case v1::PROJECTION_AXIS_Z: view.axis = ImageView::Axis::kZ; break;
    default: return Invalid("image.axis", StrCat("unknown value ", int(im.axis())));
  }
  return absl::OkStatus();
}

}  // namespace

absl::Status ConvertLook(const v1::Look& l, const std::string& path, LookParams& look,
                         bool* default_glow_radius) {
  switch (l.tone_mapping()) {
    case v1::TONE_MAPPING_UNSPECIFIED:
    case v1::TONE_MAPPING_SQRT: look.tone = ToneMapping::kSqrt; break;
    case v1::TONE_MAPPING_LOG: look.tone = ToneMapping::kLog; break;
    case v1::TONE_MAPPING_GAMMA: look.tone = ToneMapping::kGamma; break;
    case v1::TONE_MAPPING_LINEAR: look.tone = ToneMapping::kLinear; break;
    default:
      return Invalid(path + ".tone_mapping", StrCat("unknown value ", int(l.tone_mapping())));
  }
  NIMBUS_ASSIGN_OR_RETURN(look.gamma, InRangeOr(l.gamma(), 2.2, 0.1, 10, path + ".gamma"));
  NIMBUS_ASSIGN_OR_RETURN(double desat,
                          InRangeOr(l.desaturation(), 0, 0, 100, path + ".desaturation"));
  look.desaturation = desat / 100;
  NIMBUS_ASSIGN_OR_RETURN(double glow, InRangeOr(l.glow(), 0, 0, 400, path + ".glow"));
  look.glow = glow / 100;
  NIMBUS_ASSIGN_OR_RETURN(look.glow_radius,
                          InRangeOr(l.glow_radius(), 0, 1e-3, 256, path + ".glow_radius"));
  *default_glow_radius = l.glow_radius() == 0;
  NIMBUS_ASSIGN_OR_RETURN(look.brightness,
                          InRangeOr(l.brightness(), 1, 1e-6, 100, path + ".brightness"));
  const v1::Vec3& bg = l.background();
  for (auto [v, name] : {std::pair{bg.x(), "x"}, std::pair{bg.y(), "y"}, std::pair{bg.z(), "z"}})
    if (!(v >= 0 && v <= 1))
      return Invalid(StrCat(path, ".background.", name), StrCat("must be in [0, 1], got ", v));
  look.background = ToVec3(bg);
  return absl::OkStatus();
}

absl::Status ConvertImage(const v1::JobSpec& spec, JobPlan& job) {
  if (!spec.has_image()) return absl::OkStatus();
  ChaosGamePlan* cg = std::get_if<ChaosGamePlan>(&job.kind);
  if (!cg)
    return Invalid("image", "pictures are drawn for chaos_game jobs with an ifs only (not "
                            "matrices or other generators)");
  const v1::ImageOutput& im = spec.image();
  ImageJob out;
  if (!(im.width() >= 1 && im.width() <= kMaxImageSide))
    return Invalid("image.width", StrCat("must be in [1, ", kMaxImageSide, "], got ", im.width()));
  if (!(im.height() >= 0 && im.height() <= kMaxImageSide))
    return Invalid("image.height",
                   StrCat("must be in [1, ", kMaxImageSide, "] or 0 (from the aspect), got ",
                          im.height()));
  if (!(im.supersample() >= 0 && im.supersample() <= kMaxSupersample))
    return Invalid("image.supersample",
                   StrCat("must be in [1, ", kMaxSupersample, "], got ", im.supersample()));
  out.width = im.width();
  out.height = im.height();
  out.supersample = im.supersample() == 0 ? 1 : im.supersample();
  NIMBUS_RETURN_IF_ERROR(ConvertView(im, out.view));
  // The height from the aspect may grow with auto-framing: bound it by the
  // largest side.
  const int64_t rows = out.height > 0 ? out.height : kMaxImageSide;
  const int64_t samples = int64_t(out.width) * rows * out.supersample * out.supersample;
  if (out.height > 0 && samples > kMaxImageSamples)
    return absl::ResourceExhaustedError(
        StrCat("image: ", out.width, " x ", out.height, " pixels with ", out.supersample, " x ",
               out.supersample, " supersampling are ", samples,
               " samples, over the limit of 2^30 (",
               kMaxImageSamples, ")"));
  switch (im.format()) {
    case v1::IMAGE_FORMAT_UNSPECIFIED:
    case v1::IMAGE_FORMAT_PNG8: out.format = ImageFormat::kPng8; break;
    case v1::IMAGE_FORMAT_PNG16: out.format = ImageFormat::kPng16; break;
    case v1::IMAGE_FORMAT_EXR: out.format = ImageFormat::kExr; break;
    default: return Invalid("image.format", StrCat("unknown value ", int(im.format())));
  }
  NIMBUS_RETURN_IF_ERROR(ConvertLook(im.look(), "image.look", out.look, &out.default_glow_radius));
  out.look.colored = cg->params.color.mode != ColorMode::kNone;
  out.look.palette = job.density.palette;
  out.image_only = im.image_only();
  if (!(im.preview_size() == 0 || (im.preview_size() >= 16 && im.preview_size() <= 1024)))
    return Invalid("image.preview_size",
                   StrCat("must be in [16, 1024], got ", im.preview_size()));
  out.preview_size = im.preview_size() == 0 ? 256 : im.preview_size();
  if (cg->params.splat) return Invalid("chaos_game.splat", "does not apply to pictures");
  // The picture and the volume are two passes over the same walk.
  if (!out.image_only) job.work.total *= 2;
  cg->image = std::move(out);
  return absl::OkStatus();
}

absl::Status ConvertAutoFrame(const v1::JobSpec& spec, JobPlan& job) {
  if (!spec.grid().has_auto_frame() || !spec.grid().auto_frame().enabled())
    return absl::OkStatus();
  const v1::AutoFrame& a = spec.grid().auto_frame();
  const std::string path = "grid.auto_frame";
  ChaosGamePlan* cg = std::get_if<ChaosGamePlan>(&job.kind);
  if (!cg) return Invalid(path, "applies to chaos_game jobs with an ifs only");
  AutoFrameParams fit;
  NIMBUS_ASSIGN_OR_RETURN(fit.margin, InRangeOr(a.margin(), 0.05, 0, 1, path + ".margin"));
  if (!(a.pilot_iterations() == 0 ||
        (a.pilot_iterations() >= 1024 && a.pilot_iterations() <= 100'000'000)))
    return Invalid(path + ".pilot_iterations",
                   StrCat("must be in [1024, 100000000], got ", a.pilot_iterations()));
  if (a.pilot_iterations() > 0) fit.pilot_iterations = a.pilot_iterations();
  NIMBUS_ASSIGN_OR_RETURN(fit.trim, InRangeOr(a.trim(), 1e-4, 0, 0.01, path + ".trim"));
  cg->auto_frame = fit;
  return absl::OkStatus();
}

}  // namespace nimbus::spec::internal
