// Files of the picture writers: a C FILE* that closes itself (every early
// return must still close the file), and writing through a temporary file
// so that readers never see half a picture.
#pragma once

#include <cstdio>
#include <filesystem>
#include <functional>
#include <memory>
#include <system_error>

#include "absl/status/status.h"
#include "absl/strings/str_cat.h"

namespace nimbus {

struct FileCloser {
  void operator()(FILE* f) const {
    if (f) std::fclose(f);
  }
};
using FilePtr = std::unique_ptr<FILE, FileCloser>;

/// Calls write(`path`.partial) and renames that file to `path`; on failure
/// removes it and returns write's error.
inline absl::Status WriteThroughTemp(
    const std::filesystem::path& path,
    const std::function<absl::Status(const std::filesystem::path&)>& write) {
  const std::filesystem::path tmp = path.string() + ".partial";
  std::error_code ec;
  if (absl::Status st = write(tmp); !st.ok()) {
    std::filesystem::remove(tmp, ec);
    return st;
  }
  std::filesystem::rename(tmp, path, ec);
  if (ec) return absl::InternalError(absl::StrCat("renaming ", tmp.string(), ": ", ec.message()));
  return absl::OkStatus();
}

}  // namespace nimbus
