// A C FILE* that closes itself: the C libraries behind the image writers
// (libpng) take FILE*, and every early return must still close the file.
#pragma once

#include <cstdio>
#include <memory>

namespace nimbus {

struct FileCloser {
  void operator()(FILE* f) const {
    if (f) std::fclose(f);
  }
};
using FilePtr = std::unique_ptr<FILE, FileCloser>;

}  // namespace nimbus
