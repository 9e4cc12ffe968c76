#include "server/result_audit.h"

#include <algorithm>

namespace nimbus::server {

absl::StatusOr<UnknownResults> FindUnknownResults(JobStore& store,
                                                  const std::filesystem::path& results_dir,
                                                  size_t max_files) {
  std::vector<std::string> ids;
  std::error_code ec;
  for (std::filesystem::directory_iterator it(results_dir, ec), end;
       !ec && it != end && ids.size() < max_files; it.increment(ec)) {
    const std::filesystem::path& p = it->path();
    if (p.extension() == ".vdb" && it->is_regular_file(ec)) ids.push_back(p.stem().string());
  }
  std::sort(ids.begin(), ids.end());
  UnknownResults out;
  out.checked = ids.size();
  for (std::string& id : ids) {
    auto job = store.Get(id);
    if (job.ok()) continue;
    if (!absl::IsNotFound(job.status())) return job.status();
    out.ids.push_back(std::move(id));
  }
  return out;
}

}  // namespace nimbus::server
