// Previews over HTTP: the newest preview of a job through WatchJob, as the
// raw density array the console's 3D view reads and as a PNG.
#include <algorithm>
#include <cmath>
#include <cstring>
#include <optional>

#include "absl/strings/str_cat.h"
#include "core/grid/image_look.h"
#include "core/io/image_io.h"
#include "core/io/vdb_io.h"
#include "server/http_internal.h"

namespace nimbus::server::http {

namespace {
constexpr int kPreviewWaitSeconds = 15;
}

absl::StatusOr<v1::Preview> LatestPreview(ApiState& state, const httplib::Request& req,
                                          const std::string& job_id, uint32_t resolution) {
  auto ctx = CallContext(req, kPreviewWaitSeconds);
  v1::WatchJobRequest watch;
  watch.set_job_id(job_id);
  watch.set_preview_resolution(resolution);
  watch.set_preview_interval_seconds(0.05);
  auto reader = state.stub->WatchJob(ctx.get(), watch);
  v1::WatchJobResponse msg;
  std::optional<v1::Preview> found;
  while (reader->Read(&msg)) {
    if (msg.has_preview()) {
      found = std::move(*msg.mutable_preview());
      break;
    }
  }
  ctx->TryCancel();
  while (reader->Read(&msg)) {
  }
  grpc::Status st = reader->Finish();
  if (found) return std::move(*found);
  if (st.error_code() == grpc::DEADLINE_EXCEEDED || st.ok() || st.error_code() == grpc::CANCELLED)
    return absl::NotFoundError(absl::StrCat("job ", job_id, " has no preview at resolution ",
                                            resolution, " (previews exist while a job runs)"));
  return absl::Status(absl::StatusCode(st.error_code()), st.error_message());
}

absl::StatusOr<DensityArray> PreviewDensity(const v1::Preview& preview) {
  auto volume = ReadVdbBytes(preview.vdb());
  if (!volume.ok()) return volume.status();
  DensityArray out;
  out.nx = volume->frame.resolution.x;
  out.ny = volume->frame.resolution.y;
  out.nz = volume->frame.resolution.z;
  static_assert(sizeof(float) == 4);
  out.bytes.resize(volume->values.size() * 4);
  std::memcpy(out.bytes.data(), volume->values.data(), out.bytes.size());  // x86-64: LE
  return out;
}

absl::StatusOr<std::string> PreviewPng(const v1::Preview& preview) {
  if (!preview.png().empty()) return preview.png();
  auto volume = ReadVdbBytes(preview.vdb());
  if (!volume.ok()) return volume.status();
  const int nx = volume->frame.resolution.x, ny = volume->frame.resolution.y,
            nz = volume->frame.resolution.z;
  std::vector<float> sums(size_t(nx) * ny, 0.0f);
  float peak = 0;
  for (int x = 0; x < nx; ++x)
    for (int y = 0; y < ny; ++y) {
      float sum = 0;
      for (int z = 0; z < nz; ++z) sum += volume->At(x, y, z);
      sums[size_t(y) * nx + x] = sum;
      peak = std::max(peak, sum);
    }
  RgbImage image;
  image.width = nx;
  image.height = ny;
  image.rgb.assign(size_t(nx) * ny * 3, 0.0f);
  const float scale = peak > 0 ? 1.0f / std::log1p(peak) : 0.0f;
  for (int row = 0; row < ny; ++row)
    for (int x = 0; x < nx; ++x) {
      const float v = std::log1p(sums[size_t(ny - 1 - row) * nx + x]) * scale;
      float* px = image.At(x, row);
      px[0] = px[1] = px[2] = v;
    }
  return EncodePng8(image);
}

}  // namespace nimbus::server::http
