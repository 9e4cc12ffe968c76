#include "client/preview_files.h"

#include <cstdio>
#include <fstream>
#include <system_error>

#include "absl/strings/str_cat.h"

namespace nimbus::client {

std::string PreviewFileName(const std::string& job_name, uint64_t index) {
  char number[24];
  std::snprintf(number, sizeof number, "%04llu", static_cast<unsigned long long>(index));
  return absl::StrCat(job_name.empty() ? "nimbus" : job_name, ".preview.", number, ".vdb");
}

absl::StatusOr<std::optional<std::filesystem::path>> PreviewSaver::Save(
    const std::string& job_name, const v1::Preview& preview) {
  if (preview.sequence() <= last_sequence_) return std::nullopt;
  const std::filesystem::path path = dir_ / PreviewFileName(job_name, saved_ + 1);
  const std::filesystem::path tmp = path.string() + ".partial";
  {
    std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
    out.write(preview.vdb().data(), std::streamsize(preview.vdb().size()));
    out.close();
    if (!out) return absl::InternalError(absl::StrCat("cannot write ", tmp.string()));
  }
  std::error_code ec;
  std::filesystem::rename(tmp, path, ec);
  if (ec) {
    std::filesystem::remove(tmp, ec);
    return absl::InternalError(absl::StrCat("cannot rename ", tmp.string(), ": ", ec.message()));
  }
  last_sequence_ = preview.sequence();
  ++saved_;
  return path;
}

}  // namespace nimbus::client
