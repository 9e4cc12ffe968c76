#include "server/job_store_util.h"

#include <algorithm>
#include <chrono>

#include "absl/strings/escaping.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "server/bounded_text.h"
#include "server/job_event_log.h"

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

absl::Status CheckPriority(int priority) {
  if (priority >= kMinPriority && priority <= kMaxPriority) return absl::OkStatus();
  return absl::InvalidArgumentError(
      absl::StrCat("priority: must be ", kMinPriority, " to ", kMaxPriority, ", got ", priority));
}

namespace {
// One line per field: newlines inside become spaces, '=' in names '_'.
std::string OneLine(std::string s) {
  std::replace(s.begin(), s.end(), '\n', ' ');
  std::replace(s.begin(), s.end(), '\r', ' ');
  return s;
}
}  // namespace

std::string EncodeEventFields(const std::vector<std::pair<std::string, std::string>>& fields) {
  std::string out;
  for (const auto& [name, value] : fields) {
    std::string key = OneLine(BoundText(name, 64));
    std::replace(key.begin(), key.end(), '=', '_');
    absl::StrAppend(&out, key, "=", OneLine(BoundText(value, kMaxEventFieldBytes)), "\n");
  }
  return out;
}

std::vector<std::pair<std::string, std::string>> DecodeEventFields(const std::string& text) {
  std::vector<std::pair<std::string, std::string>> fields;
  size_t start = 0;
  while (start < text.size()) {
    size_t end = text.find('\n', start);
    if (end == std::string::npos) end = text.size();
    const std::string line = text.substr(start, end - start);
    const size_t eq = line.find('=');
    if (eq != std::string::npos) fields.emplace_back(line.substr(0, eq), line.substr(eq + 1));
    start = end + 1;
  }
  return fields;
}

JobEvent EndEvent(const std::string& worker_id, const Completion& c, TimeMs now) {
  if (c.state == JobState::kSucceeded)
    return {0,
            now,
            "succeeded",
            {{"worker", worker_id},
             {"size", absl::StrCat(c.result_size)},
             {"sha256", c.result_sha256}}};
  return {0,
          now,
          c.state == JobState::kCancelled ? "cancelled" : "failed",
          {{"worker", worker_id},
           {"code", absl::StatusCodeToString(static_cast<absl::StatusCode>(c.error_code))},
           {"message", c.error}}};
}

JobEvent SubmittedEvent(const NewJob& job, TimeMs now) {
  return {0,
          now,
          "submitted",
          {{"by", job.submitted_by},
           {"priority", absl::StrCat(job.priority)},
           {"retried_from", job.retried_from},
           {"cached_from", job.cached_from}}};
}

JobEvent QueuedCancelEvent(const std::string& by, TimeMs now) {
  return {0, now, "cancelled", {{"by", by}}};
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
