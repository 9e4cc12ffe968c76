// The /api/v1/ routes (docs/http_api.md): each is one gRPC call through the
// in-process channel, its bodies protobuf's JSON mapping of the messages.
#include <google/protobuf/struct.pb.h>
#include <google/protobuf/util/json_util.h>

#include <chrono>
#include <optional>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "server/http_internal.h"

namespace nimbus::server::http {

namespace {

using Stub = v1::NimbusService::Stub;
constexpr int kCallSeconds = 60;

int HttpCode(grpc::StatusCode code) {
  switch (code) {
    case grpc::OK:
      return 200;
    case grpc::INVALID_ARGUMENT:
    case grpc::OUT_OF_RANGE:
      return 400;
    case grpc::UNAUTHENTICATED:
      return 401;
    case grpc::PERMISSION_DENIED:
      return 403;
    case grpc::NOT_FOUND:
      return 404;
    case grpc::ALREADY_EXISTS:
    case grpc::ABORTED:
    case grpc::FAILED_PRECONDITION:
      return 409;
    case grpc::RESOURCE_EXHAUSTED:
      return 429;
    case grpc::CANCELLED:
      return 499;
    case grpc::UNIMPLEMENTED:
      return 501;
    case grpc::UNAVAILABLE:
      return 503;
    case grpc::DEADLINE_EXCEEDED:
      return 504;
    default:
      return 500;
  }
}

std::string JsonEscaped(const std::string& text) {
  google::protobuf::Value v;
  v.set_string_value(text);
  std::string out;
  (void)google::protobuf::util::MessageToJsonString(v, &out);
  return out;
}

std::string ToJson(const google::protobuf::Message& m) {
  google::protobuf::util::JsonPrintOptions options;
  options.always_print_primitive_fields = true;
  std::string out;
  (void)google::protobuf::util::MessageToJsonString(m, &out, options);
  return out;
}

void SendJson(httplib::Response& res, const google::protobuf::Message& m) {
  res.set_content(ToJson(m) + "\n", "application/json");
}

// Mutating calls must be JSON: a cross-site form or a "simple" fetch cannot
// send that type without a CORS preflight, which this server never grants.
bool RequireJson(const httplib::Request& req, httplib::Response& res) {
  const std::string type = req.get_header_value("Content-Type");
  if (type.rfind("application/json", 0) == 0) return true;
  SendError(res, grpc::INVALID_ARGUMENT,
            "Content-Type: send application/json (mutating calls take JSON bodies)");
  res.status = 415;
  return false;
}

// Parses a JSON body into `m`; an empty body leaves it empty.
bool ParseBody(const httplib::Request& req, httplib::Response& res, google::protobuf::Message& m) {
  if (req.body.empty()) return true;
  google::protobuf::util::JsonParseOptions options;
  auto st = google::protobuf::util::JsonStringToMessage(req.body, &m, options);
  if (st.ok()) return true;
  SendError(res, grpc::INVALID_ARGUMENT,
            absl::StrCat("body: not a ", m.GetDescriptor()->full_name(),
                         " in JSON: ", std::string(st.message())));
  return false;
}

template <typename Req, typename Resp>
void Call(Stub& stub, grpc::Status (Stub::*method)(grpc::ClientContext*, const Req&, Resp*),
          const httplib::Request& http_req, httplib::Response& res, const Req& req) {
  auto ctx = CallContext(http_req, kCallSeconds);
  Resp resp;
  grpc::Status st = (stub.*method)(ctx.get(), req, &resp);
  if (!st.ok()) return SendError(res, st);
  SendJson(res, resp);
}

// ?state=RUNNING or JOB_STATE_RUNNING.
std::optional<v1::JobState> ParseState(const std::string& text) {
  const auto* e = v1::JobState_descriptor();
  const auto* value = e->FindValueByName(text);
  if (!value) value = e->FindValueByName("JOB_STATE_" + text);
  if (!value) return std::nullopt;
  return v1::JobState(value->number());
}

void ListJobs(ApiState& s, const httplib::Request& req, httplib::Response& res) {
  v1::ListJobsRequest list;
  if (req.has_param("page_size")) {
    int n = 0;
    if (!absl::SimpleAtoi(req.get_param_value("page_size"), &n) || n < 0)
      return SendError(res, grpc::INVALID_ARGUMENT, "page_size: not a whole number >= 0");
    list.set_page_size(n);
  }
  list.set_page_token(req.get_param_value("page_token"));
  if (req.has_param("state")) {
    auto state = ParseState(req.get_param_value("state"));
    if (!state)
      return SendError(res, grpc::INVALID_ARGUMENT,
                       "state: one of QUEUED, RUNNING, SUCCEEDED, FAILED, CANCELLED");
    list.set_state(*state);
  }
  Call(*s.stub, &Stub::ListJobs, req, res, list);
}

void SubmitJob(ApiState& s, const httplib::Request& req, httplib::Response& res) {
  if (!RequireJson(req, res)) return;
  v1::SubmitJobRequest submit;
  if (!ParseBody(req, res, submit)) return;
  Call(*s.stub, &Stub::SubmitJob, req, res, submit);
}

void PinJob(ApiState& s, const httplib::Request& req, httplib::Response& res) {
  if (!RequireJson(req, res)) return;
  v1::PinJobRequest pin;
  pin.set_pinned(true);
  if (!ParseBody(req, res, pin)) return;
  pin.set_job_id(req.matches[1]);
  Call(*s.stub, &Stub::PinJob, req, res, pin);
}

// The file `name` (empty: the main file) of a job's result, its size and
// hash as GetJob lists them.
struct FileEntry {
  std::string name;
  uint64_t size = 0;
  std::string sha256;
};

grpc::Status FindFile(ApiState& s, const httplib::Request& req, const std::string& id,
                      const std::string& name, FileEntry& out) {
  auto ctx = CallContext(req, kCallSeconds);
  v1::GetJobRequest get;
  get.set_job_id(id);
  v1::GetJobResponse job;
  grpc::Status st = s.stub->GetJob(ctx.get(), get, &job);
  if (!st.ok()) return st;
  const v1::ResultInfo& result = job.job().result();
  if (name.empty()) {
    if (result.file_name().empty())
      return grpc::Status(grpc::FAILED_PRECONDITION,
                          absl::StrCat("job ", id, " has no result yet"));
    out = {result.file_name(), result.size_bytes(), result.sha256()};
    return grpc::Status::OK;
  }
  for (const v1::ResultFile& f : result.files())
    if (f.file_name() == name) {
      out = {f.file_name(), f.size_bytes(), f.sha256()};
      return grpc::Status::OK;
    }
  return grpc::Status(grpc::NOT_FOUND,
                      absl::StrCat("job ", id, " has no result file ", JsonEscaped(name)));
}

// Streams [offset, offset + length) of the file through FetchResult.
bool WriteRange(ApiState& s, const httplib::Request& req, const std::string& id,
                const std::string& name, size_t offset, size_t length, httplib::DataSink& sink) {
  auto ctx = CallContext(req, 0);
  v1::FetchResultRequest fetch;
  fetch.set_job_id(id);
  fetch.set_offset(offset);
  fetch.set_file_name(name);
  auto reader = s.stub->FetchResult(ctx.get(), fetch);
  v1::FetchResultResponse chunk;
  size_t left = length;
  while (left > 0 && reader->Read(&chunk)) {
    const size_t n = std::min(left, chunk.data().size());
    if (!sink.write(chunk.data().data(), n)) break;
    s.metrics->AddDownloadBytes(n);
    left -= n;
  }
  ctx->TryCancel();
  while (reader->Read(&chunk)) {
  }
  (void)reader->Finish();
  return left == 0;
}

// Whether every range of the request lies (at least partly) inside a file
// of `size` bytes; httplib answers the others with a bogus length.
bool RangesSatisfiable(const httplib::Ranges& ranges, uint64_t size) {
  for (const auto& [first, last] : ranges) {
    if (first < 0 ? last <= 0 : (uint64_t(first) >= size || (last >= 0 && last < first)))
      return false;
  }
  return true;
}

void Download(std::shared_ptr<ApiState> s, const httplib::Request& req, httplib::Response& res,
              const std::string& name) {
  const std::string id = req.matches[1];
  FileEntry file;
  grpc::Status st = FindFile(*s, req, id, name, file);
  if (!st.ok()) return SendError(res, st);
  if (!RangesSatisfiable(req.ranges, file.size)) {
    SendError(res, grpc::OUT_OF_RANGE, absl::StrCat("Range: the file has ", file.size, " bytes"));
    res.status = 416;
    res.set_header("Content-Range", absl::StrCat("bytes */", file.size));
    return;
  }
  res.set_header("Content-Disposition", absl::StrCat("attachment; filename=\"", file.name, "\""));
  res.set_header("X-Nimbus-Sha256", file.sha256);
  res.set_header("Accept-Ranges", "bytes");
  const std::string file_name = name;  // FetchResult: empty for the main file
  res.set_content_provider(
      file.size, "application/octet-stream",
      [s, req_copy = req, id, file_name](size_t offset, size_t length, httplib::DataSink& sink) {
        return WriteRange(*s, req_copy, id, file_name, offset, length, sink);
      });
}

void Preview(ApiState& s, const httplib::Request& req, httplib::Response& res, bool png) {
  uint32_t resolution = 64;
  if (req.has_param("resolution") &&
      (!absl::SimpleAtoi(req.get_param_value("resolution"), &resolution) || resolution < 4 ||
       resolution > 512))
    return SendError(res, grpc::INVALID_ARGUMENT, "resolution: a whole number from 4 to 512");
  auto preview = LatestPreview(s, req, req.matches[1], resolution);
  if (!preview.ok())
    return SendError(res, grpc::StatusCode(preview.status().code()),
                     std::string(preview.status().message()));
  res.set_header("X-Nimbus-Preview-Sequence", absl::StrCat(preview->sequence()));
  res.set_header("X-Nimbus-Preview-Done", absl::StrCat(preview->done()));
  res.set_header("Cache-Control", "no-store");
  if (png) {
    auto bytes = PreviewPng(*preview);
    if (!bytes.ok()) return SendError(res, grpc::INTERNAL, std::string(bytes.status().message()));
    s.metrics->AddPreviewBytes(bytes->size());
    return res.set_content(*bytes, "image/png");
  }
  auto density = PreviewDensity(*preview);
  if (!density.ok()) return SendError(res, grpc::INTERNAL, std::string(density.status().message()));
  res.set_header("X-Nimbus-Shape", absl::StrCat(density->nx, ",", density->ny, ",", density->nz));
  s.metrics->AddPreviewBytes(density->bytes.size());
  res.set_content(density->bytes, "application/octet-stream");
}

}  // namespace

std::unique_ptr<grpc::ClientContext> CallContext(const httplib::Request& req, int seconds) {
  auto ctx = std::make_unique<grpc::ClientContext>();
  if (req.has_header("Authorization"))
    ctx->AddMetadata("authorization", req.get_header_value("Authorization"));
  if (seconds > 0)
    ctx->set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(seconds));
  return ctx;
}

void SendError(httplib::Response& res, grpc::StatusCode code, const std::string& message) {
  res.status = HttpCode(code);
  const std::string name = absl::StatusCodeToString(absl::StatusCode(code));
  res.set_content(absl::StrCat("{\"error\":{\"code\":", int(code), ",\"status\":\"", name,
                               "\",\"message\":", JsonEscaped(message), "}}\n"),
                  "application/json");
  if (code == grpc::UNAUTHENTICATED) res.set_header("WWW-Authenticate", "Bearer");
}

void SendError(httplib::Response& res, const grpc::Status& status) {
  SendError(res, status.error_code(), status.error_message());
}

void RegisterStreams(httplib::Server& server, std::shared_ptr<ApiState> state);

bool PlausibleId(const std::string& id) {
  if (id.empty() || id.size() > 256) return false;
  for (unsigned char c : id)
    if (c <= ' ' || c >= 0x7f || c == '/' || c == '\\') return false;
  return true;
}

void RegisterApi(httplib::Server& server, std::shared_ptr<ApiState> s) {
  // Job ids are printable ASCII: anything else names no job (and never
  // reaches gRPC, whose strings must be UTF-8).
  server.set_pre_routing_handler([](const httplib::Request& req, httplib::Response& res) {
    constexpr absl::string_view kJobs = "/api/v1/jobs/";
    if (req.path.rfind(kJobs.data(), 0) != 0) return httplib::Server::HandlerResponse::Unhandled;
    const std::string rest = req.path.substr(kJobs.size());
    if (PlausibleId(rest.substr(0, rest.find('/'))))
      return httplib::Server::HandlerResponse::Unhandled;
    SendError(res, grpc::NOT_FOUND, "no such job");
    return httplib::Server::HandlerResponse::Handled;
  });
  const std::string job = "/api/v1/jobs/([^/]+)";
  server.Get("/api/v1/jobs", [s](const auto& req, auto& res) { ListJobs(*s, req, res); });
  server.Post("/api/v1/jobs", [s](const auto& req, auto& res) { SubmitJob(*s, req, res); });
  server.Get(job, [s](const httplib::Request& req, httplib::Response& res) {
    v1::GetJobRequest get;
    get.set_job_id(req.matches[1]);
    Call(*s->stub, &Stub::GetJob, req, res, get);
  });
  server.Post(job + "/cancel", [s](const httplib::Request& req, httplib::Response& res) {
    if (!RequireJson(req, res)) return;
    v1::CancelJobRequest cancel;
    cancel.set_job_id(req.matches[1]);
    Call(*s->stub, &Stub::CancelJob, req, res, cancel);
  });
  server.Post(job + "/pin", [s](const auto& req, auto& res) { PinJob(*s, req, res); });
  server.Delete(job, [s](const httplib::Request& req, httplib::Response& res) {
    if (!RequireJson(req, res)) return;
    v1::DeleteJobRequest del;
    del.set_job_id(req.matches[1]);
    Call(*s->stub, &Stub::DeleteJob, req, res, del);
  });
  server.Get(job + "/result", [s](const auto& req, auto& res) { Download(s, req, res, ""); });
  server.Get(job + "/files/([^/]+)", [s](const httplib::Request& req, httplib::Response& res) {
    Download(s, req, res, req.matches[2]);
  });
  server.Get(job + "/preview.png",
             [s](const auto& req, auto& res) { Preview(*s, req, res, true); });
  server.Get(job + "/preview.density",
             [s](const auto& req, auto& res) { Preview(*s, req, res, false); });
  // What this server offers beyond the job calls, so clients (the console)
  // show the queue's pages only where the server has them.
  server.Get("/api/v1/info", [](const httplib::Request&, httplib::Response& res) {
    std::string features = "\"jobs\",\"previews\",\"stream\",\"metrics\"";
    for (const std::string& f : QueueFeatures()) absl::StrAppend(&features, ",\"", f, "\"");
    res.set_content(absl::StrCat("{\"api\":\"v1\",\"features\":[", features, "]}\n"),
                    "application/json");
  });
  RegisterQueue(server, s);
  RegisterStreams(server, s);
  server.set_error_handler([](const httplib::Request& req, httplib::Response& res) {
    if (!res.body.empty()) return;
    if (res.status == 404)
      SendError(res, grpc::NOT_FOUND, "no such path");
    else if (res.status == 413)
      SendError(res, grpc::RESOURCE_EXHAUSTED, "request body too large");
    else
      return;
    if (res.status == 429) res.status = 413;
  });
}

}  // namespace nimbus::server::http
