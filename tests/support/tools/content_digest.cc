// Prints the decoded-content digest (tests/support/decoded_content.h) of
// every file named, or found under a folder named, one "DIGEST  PATH" line
// each, folders' files sorted by path. Exit 1 when a file cannot be read.
//
//   content_digest out/tree.vdb out/frames/
#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

#include "tests/support/decoded_content.h"

int main(int argc, char** argv) {
  std::vector<std::filesystem::path> files;
  for (int i = 1; i < argc; ++i) {
    const std::filesystem::path p(argv[i]);
    if (!std::filesystem::is_directory(p)) {
      files.push_back(p);
      continue;
    }
    std::vector<std::filesystem::path> found;
    for (const auto& e : std::filesystem::recursive_directory_iterator(p))
      if (e.is_regular_file()) found.push_back(e.path());
    std::sort(found.begin(), found.end());
    files.insert(files.end(), found.begin(), found.end());
  }
  int rc = 0;
  for (const auto& f : files) {
    auto digest = nimbus::testing::ContentDigest(f);
    if (!digest.ok()) {
      std::fprintf(stderr, "%s: %s\n", f.c_str(), std::string(digest.status().message()).c_str());
      rc = 1;
      continue;
    }
    std::printf("%s  %s\n", digest->c_str(), f.c_str());
  }
  return rc;
}
