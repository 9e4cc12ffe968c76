// @brief Saves the previews of a watch as files a DCC image-sequence import
// reads without gaps: NAME.preview.0001.vdb, 0002, … in arrival order,
// whatever sequence numbers the server skipped for a slow watcher. The
// server writes the sequence and the work done into each preview's
// metadata (nimbus_preview_sequence, nimbus_preview_done), so the dense
// file number loses nothing.
#pragma once

#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>

#include "absl/status/statusor.h"
#include "nimbus/v1/nimbus_service.pb.h"

namespace nimbus::client {

/// "NAME.preview.0007.vdb" for index 7 (1-based); "nimbus" for an empty name.
std::string PreviewFileName(const std::string& job_name, uint64_t index);

/// The preview picture saved beside a preview grid: NAME.preview.0007.png.
std::filesystem::path PreviewPngPath(const std::filesystem::path& vdb_path);

/// Saves each preview's grid, and its PNG when it carries one (jobs with
/// an image) beside it with the same number.
class PreviewSaver {
 public:
  explicit PreviewSaver(std::filesystem::path dir) : dir_(std::move(dir)) {}

  /// Writes `preview` as the next dense file, through a ".partial" file
  /// renamed into place so a reader never opens half a preview. A preview
  /// whose sequence is not newer than the last saved (a re-attached watch
  /// repeats the latest) is skipped: nullopt.
  absl::StatusOr<std::optional<std::filesystem::path>> Save(const std::string& job_name,
                                                           const v1::Preview& preview);
  /// Previews saved so far.
  uint64_t saved() const { return saved_; }

 private:
  std::filesystem::path dir_;
  uint64_t saved_ = 0;
  uint64_t last_sequence_ = 0;
};

}  // namespace nimbus::client
