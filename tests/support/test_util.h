// Helpers shared by the tests: scratch folders and paths into the source tree.
// Test servers bind port 0 and report the port they got (nimbusd_process.h).
#pragma once

#include <filesystem>
#include <string>

namespace nimbus::testing {

/// A fresh, empty folder removed again when the object dies.
class TempDir {
 public:
  TempDir();
  ~TempDir();
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
  const std::filesystem::path& path() const { return path_; }
  std::filesystem::path operator/(const std::string& name) const { return path_ / name; }

 private:
  std::filesystem::path path_;
};

/// Absolute path of a file in the source tree, e.g. SourcePath("examples/tree.json").
std::filesystem::path SourcePath(const std::string& relative);

/// A whole file's bytes; empty when it cannot be read.
std::string ReadFileBytes(const std::filesystem::path& path);

}  // namespace nimbus::testing
