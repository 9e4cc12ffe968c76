#include "server/json_log.h"

#include <grpc/support/log.h>
#include <spdlog/spdlog.h>

#include <chrono>
#include <ctime>
#include <utility>
#include <vector>

#include "absl/strings/ascii.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"

namespace nimbus::server {

namespace {

// Length of the UTF-8 sequence starting at s[i], or 0 when it is not one.
size_t Utf8Length(absl::string_view s, size_t i) {
  const auto byte = [&](size_t k) { return static_cast<unsigned char>(s[k]); };
  const unsigned char c = byte(i);
  size_t n = c < 0x80 ? 1 : (c >> 5) == 0x6 ? 2 : (c >> 4) == 0xe ? 3 : (c >> 3) == 0x1e ? 4 : 0;
  if (n == 0 || i + n > s.size()) return 0;
  for (size_t k = 1; k < n; ++k)
    if ((byte(i + k) & 0xc0) != 0x80) return 0;
  return n;
}

void AppendJsonString(std::string& out, absl::string_view s) {
  out += '"';
  for (size_t i = 0; i < s.size();) {
    const unsigned char c = static_cast<unsigned char>(s[i]);
    const size_t n = Utf8Length(s, i);
    if (n == 0) {
      out += "\\ufffd";
      ++i;
      continue;
    }
    if (c == '"' || c == '\\') {
      out += '\\';
      out += char(c);
    } else if (c == '\n') {
      out += "\\n";
    } else if (c == '\t') {
      out += "\\t";
    } else if (c < 0x20 || c == 0x7f) {
      out += absl::StrFormat("\\u%04x", c);
    } else {
      out.append(s.data() + i, n);
    }
    i += n;
  }
  out += '"';
}

// A value written bare: a whole decimal number or a boolean.
bool IsBareValue(absl::string_view v) {
  if (v == "true" || v == "false") return true;
  int64_t n = 0;
  return absl::SimpleAtoi(v, &n) && absl::StrCat(n) == v;
}

struct Parsed {
  std::vector<std::pair<std::string, std::string>> pairs;
  std::string text;  // words that are not key=value
};

// A key: letters, digits and '_' before '='.
size_t KeyLength(absl::string_view s) {
  size_t k = 0;
  while (k < s.size() && (absl::ascii_isalnum(s[k]) || s[k] == '_')) ++k;
  return k > 0 && k < s.size() && s[k] == '=' ? k : 0;
}

// The value at the start of `s` (quoted with \" inside, or up to a space);
// `used` gets the bytes it took.
std::string TakeValue(absl::string_view s, size_t& used) {
  if (s.empty() || s[0] != '"') {
    used = std::min(s.find(' '), s.size());
    return std::string(s.substr(0, used));
  }
  std::string v;
  size_t i = 1;
  for (; i < s.size() && s[i] != '"'; ++i) {
    if (s[i] == '\\' && i + 1 < s.size() && s[i + 1] == '"') ++i;
    v += s[i];
  }
  used = std::min(i + 1, s.size());
  return v;
}

Parsed ParseMessage(absl::string_view s) {
  Parsed p;
  while (!s.empty()) {
    if (s[0] == ' ') {
      s.remove_prefix(1);
      continue;
    }
    if (const size_t k = KeyLength(s); k > 0) {
      size_t used = 0;
      std::string value = TakeValue(s.substr(k + 1), used);
      p.pairs.emplace_back(std::string(s.substr(0, k)), std::move(value));
      s.remove_prefix(k + 1 + used);
      continue;
    }
    const size_t word = std::min(s.find(' '), s.size());
    absl::StrAppend(&p.text, p.text.empty() ? "" : " ", s.substr(0, word));
    s.remove_prefix(word);
  }
  return p;
}

}  // namespace

std::string LogLineJson(absl::string_view time, absl::string_view level, absl::string_view replica,
                        absl::string_view message) {
  const Parsed parsed = ParseMessage(message);
  std::string out = "{\"time\":";
  AppendJsonString(out, time);
  out += ",\"level\":";
  AppendJsonString(out, level);
  out += ",\"replica\":";
  AppendJsonString(out, replica);
  std::string fields;
  for (const auto& [key, value] : parsed.pairs) {
    const bool top = key == "job" || key == "event";
    std::string& into = top ? out : fields;
    if (!top && !into.empty()) into += ',';
    if (top) into += ',';
    AppendJsonString(into, key);
    into += ':';
    if (!top && IsBareValue(value))
      into += value;
    else
      AppendJsonString(into, value);
  }
  if (!parsed.text.empty()) {
    out += ",\"message\":";
    AppendJsonString(out, parsed.text);
  }
  if (!fields.empty()) absl::StrAppend(&out, ",\"fields\":{", fields, "}");
  out += "}";
  return out;
}

void JsonLogFormatter::format(const spdlog::details::log_msg& msg, spdlog::memory_buf_t& dest) {
  const auto since = msg.time.time_since_epoch();
  const std::time_t seconds = std::chrono::duration_cast<std::chrono::seconds>(since).count();
  const int ms = int(std::chrono::duration_cast<std::chrono::milliseconds>(since).count() % 1000);
  std::tm utc{};
  ::gmtime_r(&seconds, &utc);
  char stamp[32];
  std::strftime(stamp, sizeof(stamp), "%Y-%m-%dT%H:%M:%S", &utc);
  const spdlog::string_view_t level = spdlog::level::to_string_view(msg.level);
  const std::string line = LogLineJson(
      absl::StrFormat("%s.%03dZ", stamp, ms), absl::string_view(level.data(), level.size()),
      replica_, absl::string_view(msg.payload.data(), msg.payload.size()));
  dest.append(line.data(), line.data() + line.size());
  dest.push_back('\n');
}

void RouteGrpcLogsToSpdlog() {
  gpr_set_log_function([](gpr_log_func_args* args) {
    const spdlog::level::level_enum level = args->severity == GPR_LOG_SEVERITY_ERROR ? spdlog::level::err
                                            : args->severity == GPR_LOG_SEVERITY_INFO
                                                ? spdlog::level::info
                                                : spdlog::level::debug;
    spdlog::log(level, "event=grpc_log file={} line={} message=\"{}\"",
                args->file == nullptr ? "" : args->file, args->line,
                args->message == nullptr ? "" : args->message);
  });
}

}  // namespace nimbus::server
