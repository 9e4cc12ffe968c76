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

namespace {

// Writes `bytes` through a ".partial" file renamed into place.
absl::Status WriteAtomically(const std::filesystem::path& path, const std::string& bytes) {
  const std::filesystem::path tmp = path.string() + ".partial";
  {
    std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
    out.write(bytes.data(), std::streamsize(bytes.size()));
    out.close();
    if (!out) return absl::InternalError(absl::StrCat("cannot write ", tmp.string()));
  }
  std::error_code ec;
  std::filesystem::rename(tmp, path, ec);
  if (ec) {
    std::filesystem::remove(tmp, ec);
    return absl::InternalError(absl::StrCat("cannot rename ", tmp.string(), ": ", ec.message()));
  }
  return absl::OkStatus();
}

}  // namespace

std::filesystem::path PreviewPngPath(const std::filesystem::path& vdb_path) {
  std::filesystem::path p = vdb_path;
  return p.replace_extension(".png");
}

absl::StatusOr<std::optional<std::filesystem::path>> PreviewSaver::Save(
    const std::string& job_name, const v1::Preview& preview) {
  if (preview.sequence() <= last_sequence_) return std::nullopt;
  const std::filesystem::path path = dir_ / PreviewFileName(job_name, saved_ + 1);
  // The picture first: a reader that sees the grid finds its picture too.
  if (!preview.png().empty())
    if (absl::Status st = WriteAtomically(PreviewPngPath(path), preview.png()); !st.ok())
      return st;
  if (absl::Status st = WriteAtomically(path, preview.vdb()); !st.ok()) return st;
  last_sequence_ = preview.sequence();
  ++saved_;
  return path;
}

}  // namespace nimbus::client
