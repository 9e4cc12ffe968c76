// Helpers shared by the tests: scratch folders and paths into the source tree.
// Test servers bind port 0 and report the port they got (nimbusd_process.h).
#pragma once

#include <atomic>
#include <filesystem>
#include <string>

#include "core/base/interrupter.h"

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

/// What `ldd` prints for `object`: every library the dynamic linker would
/// load for it (empty when ldd cannot run).
std::string Ldd(const std::string& object);

/// Lets `polls` polls pass, then interrupts every later one (from any
/// thread).
class CancelAfter : public Interrupter {
 public:
  explicit CancelAfter(int polls) : left_(polls) {}
  bool WasInterrupted(uint64_t, uint64_t) override { return --left_ < 0; }

 private:
  std::atomic<int> left_;
};

}  // namespace nimbus::testing
