// GET /api/v1/jobs/{id}/stream: Server-Sent Events of one job from
// WatchJob. WatchJob sends the newest state and preview, skipping what a
// slow reader missed, so a slow browser never builds a queue here either.
#include <google/protobuf/util/json_util.h>

#include <algorithm>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "server/http_internal.h"

namespace nimbus::server::http {

namespace {

// How long one WatchJob of a stream lasts: then the stream sends a comment
// and watches again, so a reader that went away is noticed (its slot and
// thread freed) even while the job sends nothing, and proxies see traffic.
constexpr int kWatchSeconds = 15;

struct Stream {
  std::shared_ptr<ApiState> state;
  httplib::Request req;
  v1::WatchJobRequest watch;
  std::unique_ptr<grpc::ClientContext> ctx;
  std::unique_ptr<grpc::ClientReader<v1::WatchJobResponse>> reader;
  bool ended = false;
  /// With events: the newest event seq sent, where a renewed watch resumes.
  int64_t last_event_seq = 0;

  void Open() {
    if (watch.include_events()) watch.set_events_after_seq(last_event_seq);
    ctx = CallContext(req, kWatchSeconds);
    reader = state->stub->WatchJob(ctx.get(), watch);
  }

  ~Stream() {
    if (reader) {
      ctx->TryCancel();
      v1::WatchJobResponse rest;
      while (reader->Read(&rest)) {
      }
      (void)reader->Finish();
    }
    state->open_streams.fetch_sub(1);
  }
};

std::string Event(const char* name, const std::string& data) {
  return absl::StrCat("event: ", name, "\ndata: ", data, "\n\n");
}

// One message of the watch as events: "job" (the view, spec omitted),
// when it carries one, "preview" (its sequence, work done and shape), and
// one "event" per entry of the job's event log it carries (a JobEvent).
std::string Events(const v1::WatchJobResponse& msg, Stream& s) {
  google::protobuf::util::JsonPrintOptions options;
  options.always_print_primitive_fields = true;
  std::string job;
  (void)google::protobuf::util::MessageToJsonString(msg.job(), &job, options);
  std::string out = Event("job", job);
  if (msg.has_preview()) {
    v1::Preview header = msg.preview();
    header.clear_vdb();
    header.clear_png();
    std::string preview;
    (void)google::protobuf::util::MessageToJsonString(header, &preview, options);
    out += Event("preview", preview);
  }
  for (const v1::JobEvent& e : msg.events()) {
    std::string event;
    (void)google::protobuf::util::MessageToJsonString(e, &event, options);
    out += Event("event", event);
    s.last_event_seq = std::max(s.last_event_seq, e.seq());
  }
  return out;
}

bool Pump(Stream& s, httplib::DataSink& sink) {
  if (s.ended) return false;
  v1::WatchJobResponse msg;
  if (s.reader->Read(&msg)) {
    const std::string text = Events(msg, s);
    return sink.write(text.data(), text.size());
  }
  grpc::Status st = s.reader->Finish();
  s.reader.reset();
  if (st.error_code() == grpc::DEADLINE_EXCEEDED) {
    static constexpr char kKeepAlive[] = ": keep-alive\n\n";
    if (!sink.write(kKeepAlive, sizeof(kKeepAlive) - 1)) return false;
    s.Open();
    return true;
  }
  s.ended = true;
  const std::string end =
      st.ok() ? Event("end", "{}")
              : Event("error", absl::StrCat("{\"code\":", int(st.error_code()), "}"));
  sink.write(end.data(), end.size());
  sink.done();
  return true;
}

// The stream's event log parameters: events=1 (or true) asks for it,
// events_after_seq=N starts after seq N. False with an error sent.
bool EventParams(const httplib::Request& req, httplib::Response& res, v1::WatchJobRequest& watch) {
  const std::string on = req.has_param("events") ? req.get_param_value("events") : "0";
  if (on != "0" && on != "1" && on != "true" && on != "false") {
    SendError(res, grpc::INVALID_ARGUMENT, "events: 1, 0, true or false");
    return false;
  }
  int64_t after = 0;
  if (req.has_param("events_after_seq") &&
      (!absl::SimpleAtoi(req.get_param_value("events_after_seq"), &after) || after < 0)) {
    SendError(res, grpc::INVALID_ARGUMENT, "events_after_seq: a whole number, 0 or more");
    return false;
  }
  watch.set_include_events(on == "1" || on == "true");
  watch.set_events_after_seq(after);
  return true;
}

void OpenStream(std::shared_ptr<ApiState> state, const httplib::Request& req,
                httplib::Response& res) {
  uint32_t resolution = 0;
  double interval = 1.0;
  if (req.has_param("preview_resolution") &&
      (!absl::SimpleAtoi(req.get_param_value("preview_resolution"), &resolution) ||
       resolution > 512))
    return SendError(res, grpc::INVALID_ARGUMENT, "preview_resolution: 0 to 512");
  if (req.has_param("preview_interval") &&
      (!absl::SimpleAtod(req.get_param_value("preview_interval"), &interval) ||
       !(interval >= 0.05 && interval <= 3600)))
    return SendError(res, grpc::INVALID_ARGUMENT, "preview_interval: 0.05 to 3600 seconds");
  v1::WatchJobRequest watch;
  if (!EventParams(req, res, watch)) return;
  // Unknown or foreign jobs are answered 404 before the stream starts.
  v1::GetJobRequest get;
  get.set_job_id(req.matches[1]);
  v1::GetJobResponse job;
  grpc::Status st = state->stub->GetJob(CallContext(req, 30).get(), get, &job);
  if (!st.ok()) return SendError(res, st);
  if (state->open_streams.fetch_add(1) >= state->max_streams) {
    state->open_streams.fetch_sub(1);
    SendError(res, grpc::UNAVAILABLE, "too many open event streams; try again later");
    res.set_header("Retry-After", "5");
    return;
  }
  auto stream = std::make_shared<Stream>();
  stream->state = state;
  stream->req = req;
  stream->watch = watch;
  stream->last_event_seq = watch.events_after_seq();
  stream->watch.set_job_id(req.matches[1]);
  stream->watch.set_preview_resolution(resolution);
  stream->watch.set_preview_interval_seconds(interval);
  stream->Open();
  res.set_header("Cache-Control", "no-store");
  res.set_header("X-Accel-Buffering", "no");
  res.set_chunked_content_provider("text/event-stream", [stream](size_t, httplib::DataSink& sink) {
    return Pump(*stream, sink);
  });
}

}  // namespace

void RegisterStreams(httplib::Server& server, std::shared_ptr<ApiState> state) {
  server.Get("/api/v1/jobs/([^/]+)/stream",
             [state](const auto& req, auto& res) { OpenStream(state, req, res); });
}

}  // namespace nimbus::server::http
