#include "server/job_store_util.h"

#include <algorithm>
#include <chrono>

#include "absl/strings/escaping.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "server/bounded_text.h"

namespace nimbus::server {

std::string EncodePageToken(TimeMs create_time, const std::string& id) {
  return absl::WebSafeBase64Escape(absl::StrCat(create_time, ":", id));
}

absl::Status DecodePageToken(const std::string& token, TimeMs* create_time, std::string* id) {
  std::string raw;
  absl::Status bad =
      absl::InvalidArgumentError(absl::StrCat("invalid page_token \"", EchoId(token), "\""));
  if (!absl::WebSafeBase64Unescape(token, &raw)) return bad;
  const size_t colon = raw.find(':');
  if (colon == std::string::npos) return bad;
  if (!absl::SimpleAtoi(raw.substr(0, colon), create_time)) return bad;
  *id = raw.substr(colon + 1);
  return absl::OkStatus();
}

uint64_t ViewBytes(const JobRecord& r) {
  const auto bounded = [](const std::string& s, size_t max) {
    return std::min<uint64_t>(s.size(), max + 64);
  };
  return 256 + r.id.size() + bounded(r.name, kMaxJobNameBytes) * 2 +
         bounded(r.error, kMaxErrorBytes) * 2 + bounded(r.warnings, kMaxWarningsBytes) +
         r.result_sha256.size();
}

TimeMs WallClockMs() {
  return std::chrono::duration_cast<std::chrono::milliseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}

std::string RedactUrl(const std::string& url) {
  const size_t scheme = url.find("://");
  const size_t at = url.find('@');
  if (scheme == std::string::npos || at == std::string::npos || at < scheme) return url;
  const size_t colon = url.find(':', scheme + 3);
  if (colon == std::string::npos || colon > at) return url;
  return absl::StrCat(url.substr(0, colon), ":***", url.substr(at));
}

}  // namespace nimbus::server
