// Runs fractal-field jobs (docs/fractal_fields.md): the shape's signed
// distance first (the preparing phase), then one field evaluation per frame.
// A density job writes fog volumes; a terrain job writes a level set and a
// 16-bit PNG height map. Animated jobs write every frame as NAME.0001.vdb...
// as soon as it is done (fetchable while the job runs); the main result is
// frame 1.
#include <chrono>
#include <optional>

#include "absl/strings/str_cat.h"
#include "core/base/status_macros.h"
#include "core/field/field_render.h"
#include "server/job_driver.h"

namespace nimbus::server {

namespace {

using Clock = std::chrono::steady_clock;

const char* InterpolationName(FieldInterpolation i) {
  switch (i) {
    case FieldInterpolation::kLinear: return "linear";
    case FieldInterpolation::kPseudoCubic: return "pseudo_cubic";
    case FieldInterpolation::kQuintic: return "quintic";
    case FieldInterpolation::kCubic: return "cubic";
  }
  return "linear";
}

// A coarse copy for watchers: densities quantised to 1/255.
CountGrid PreviewCounts(const FloatVolume& vol) {
  CountGrid counts(vol.frame.resolution);
  const Int3 r = vol.frame.resolution;
  size_t i = 0;
  for (int x = 0; x < r.x; ++x)
    for (int y = 0; y < r.y; ++y)
      for (int z = 0; z < r.z; ++z, ++i)
        if (const uint32_t c = uint32_t(vol.values[i] * 255.f + 0.5f)) counts.Add(x, y, z, c);
  return counts;
}

/// @brief One frame's outputs: the volume written as the frame (and kept
/// as the main result for frame 0).
class FieldFrames {
 public:
  FieldFrames(const FractalFieldPlan& k, JobDriver& d) : k_(k), d_(d), field_(k.field) {}

  absl::Status Prepare() {
    NIMBUS_RETURN_IF_ERROR(d_.BeginPhase(JobPhase::kPreparing, 1, "steps"));
    if (k_.shape) {
      auto sdf = ShapeSignedDistance(k_.shape->source, d_.plan().frame, d_.interrupter());
      if (!sdf.ok() && !absl::IsCancelled(sdf.status()))
        return absl::Status(sdf.status().code(),
                            absl::StrCat(k_.shape->source.field, ": ", sdf.status().message()));
      if (!sdf.ok()) return sdf.status();
      sdf_ = std::move(*sdf);
    }
    return d_.Progress(1, true);
  }

  // Renders and writes frame `index`; keeps frame 0 for the main result.
  absl::Status Frame(int64_t index, bool animated) {
    const double t = animated ? FrameTime(k_.animation, index) : k_.animation.time_start;
    const Metadata meta = d_.Metadata()
                              .Add(meta_key::kSeed, int64_t(k_.field.seed))
                              .Add(meta_key::kFieldDimensions, int64_t(k_.field.dims))
                              .Add(meta_key::kFieldMeshes, int64_t(k_.field.meshes.size()))
                              .Add(meta_key::kFieldInterpolation,
                                   std::string(InterpolationName(k_.field.interpolation)))
                              .Add(meta_key::kFieldOutput, std::string(Terrain() ? "terrain" : "density"))
                              .Add(meta_key::kFieldFrame, int64_t(index + 1))
                              .Add(meta_key::kFieldTime, t)
                              .Build();
    FloatVolume vol;
    if (Terrain()) {
      NIMBUS_ASSIGN_OR_RETURN(vol, TerrainFrame(index, animated, t));
    } else {
      NIMBUS_ASSIGN_OR_RETURN(vol, RenderDensity(field_, k_, d_.plan().frame, t,
                                                 sdf_ ? &*sdf_ : nullptr, d_.interrupter()));
      Modulate(vol);
      const CountGrid preview = PreviewCounts(vol);
      d_.Preview({&preview}, uint64_t(index + 1));
    }
    if (animated) NIMBUS_RETURN_IF_ERROR(d_.WriteFrame(uint64_t(index), vol, meta));
    if (index == 0) {
      first_ = std::move(vol);
      first_meta_ = meta;
    }
    return absl::OkStatus();
  }

  absl::Status WriteMain() { return d_.WriteResult(*first_, first_meta_); }

 private:
  bool Terrain() const { return k_.output == FieldOutputKind::kTerrain; }

  absl::StatusOr<FloatVolume> TerrainFrame(int64_t index, bool animated, double t) {
    NIMBUS_ASSIGN_OR_RETURN(HeightField h,
                            RenderHeights(field_, k_, d_.plan().frame, t, d_.interrupter()));
    if (k_.terrain.png) {
      const std::string name = animated ? absl::StrCat(d_.plan().name, ".", Pad(index + 1), ".png")
                                        : d_.plan().name + ".height.png";
      NIMBUS_ASSIGN_OR_RETURN(std::filesystem::path png, d_.ExtraFilePath(name));
      NIMBUS_RETURN_IF_ERROR(WritePng16(png, HeightMap16(h)));
    }
    return TerrainLevelSet(h, d_.plan().frame);
  }

  static std::string Pad(int64_t n) {
    char buf[24];
    std::snprintf(buf, sizeof buf, "%04lld", static_cast<long long>(n));
    return buf;
  }

  // JobSpec.detail on a field's own density.
  void Modulate(FloatVolume& vol) const {
    const auto& m = d_.plan().density.modulation;
    if (!m) return;
    const Int3 r = vol.frame.resolution;
    size_t i = 0;
    for (int x = 0; x < r.x; ++x)
      for (int y = 0; y < r.y; ++y)
        for (int z = 0; z < r.z; ++z, ++i)
          if (vol.values[i] != 0.f)
            vol.values[i] =
                float(double(vol.values[i]) * std::max(0.0, m(vol.frame.VoxelCenter({x, y, z}))));
  }

  const FractalFieldPlan& k_;
  JobDriver& d_;
  FractalField field_;
  std::optional<std::vector<float>> sdf_;
  std::optional<FloatVolume> first_;
  Metadata first_meta_;
};

}  // namespace

absl::Status RunKind(const JobPlan& plan, const FractalFieldPlan& kind, JobContext& ctx) {
  JobDriver d(plan, ctx);
  FieldFrames frames(kind, d);
  NIMBUS_RETURN_IF_ERROR(d.Check(frames.Prepare()));
  const bool animated = kind.animation.frames > 0;
  const int64_t count = std::max<int64_t>(kind.animation.frames, 1);
  NIMBUS_RETURN_IF_ERROR(d.BeginPhase(JobPhase::kIterating, uint64_t(count), "frames"));
  const auto start = Clock::now();
  for (int64_t f = 0; f < count; ++f) {
    if (absl::Status st = frames.Frame(f, animated); !st.ok()) {
      // A failed or cancelled animation leaves no frames behind.
      d.DiscardFrames();
      return d.Check(st);
    }
    NIMBUS_RETURN_IF_ERROR(d.Progress(uint64_t(f + 1), true));
  }
  ctx.SetStat("field_ms",
              uint64_t(std::chrono::duration<double, std::milli>(Clock::now() - start).count()));
  ctx.SetStat("frames", uint64_t(count));
  return frames.WriteMain();
}

}  // namespace nimbus::server
