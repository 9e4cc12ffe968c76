// nimbusd's log lines as JSON objects, one per line, for log collectors
// (Loki, Elasticsearch, journald).
//
//   spdlog::set_formatter(std::make_unique<JsonLogFormatter>("replica-a"));
//   spdlog::info("job={} event=submitted name={} owner={}", id, name, owner);
//   // {"time":"2026-11-29T02:38:09.273Z","level":"info","replica":"replica-a",
//   //  "job":"j-1","event":"submitted","fields":{"name":"tree","owner":"alice"}}
#pragma once

#include <spdlog/formatter.h>

#include <memory>
#include <string>

#include "absl/strings/string_view.h"

namespace nimbus::server {

/// One log message as a JSON object. Messages are written as `key=value`
/// pairs (a value in double quotes may hold spaces and `\"`); `job` and
/// `event` become top-level members, the other pairs members of `fields`
/// (whole decimal numbers and true/false as JSON numbers and booleans,
/// the rest as strings), and any text that is not a pair goes to
/// `message`. `time` is UTC with milliseconds. Bytes that are not UTF-8
/// become U+FFFD, so every line is valid JSON whatever a message holds.
std::string LogLineJson(absl::string_view time, absl::string_view level, absl::string_view replica,
                        absl::string_view message);

/// @brief A spdlog formatter writing LogLineJson lines.
class JsonLogFormatter : public spdlog::formatter {
 public:
  explicit JsonLogFormatter(std::string replica) : replica_(std::move(replica)) {}
  void format(const spdlog::details::log_msg& msg, spdlog::memory_buf_t& dest) override;
  std::unique_ptr<spdlog::formatter> clone() const override {
    return std::make_unique<JsonLogFormatter>(replica_);
  }

 private:
  std::string replica_;
};

/// Sends gRPC's own log lines (normally written to stderr in its format)
/// through spdlog as `event=grpc_log file=… line=… message="…"`, so a
/// JSON log stays one JSON object per line. Call once, before any server.
void RouteGrpcLogsToSpdlog();

}  // namespace nimbus::server
