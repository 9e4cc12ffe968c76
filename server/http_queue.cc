// The studio queue's calls (RetryJob, SetJobPriority, GetJobEvents,
// ListWorkers) over HTTP. They are looked up by name in this build's
// nimbus.v1.NimbusService descriptor and called through a generic stub, so
// the routes answer as soon as the proto has the methods and 501 until then.
#include <google/protobuf/descriptor.h>
#include <google/protobuf/message.h>
#include <google/protobuf/util/json_util.h>
#include <grpcpp/generic/generic_stub.h>

#include <future>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "server/http_internal.h"

namespace nimbus::server::http {

namespace {

const google::protobuf::MethodDescriptor* FindMethod(const std::string& name) {
  const auto* service = google::protobuf::DescriptorPool::generated_pool()->FindServiceByName(
      "nimbus.v1.NimbusService");
  return service ? service->FindMethodByName(name) : nullptr;
}

std::unique_ptr<google::protobuf::Message> NewMessage(const google::protobuf::Descriptor* type) {
  return std::unique_ptr<google::protobuf::Message>(
      google::protobuf::MessageFactory::generated_factory()->GetPrototype(type)->New());
}

// Calls `method` with `json` as its request (plus job_id from the path when
// the route has one) and answers its response as JSON.
void CallByName(ApiState& s, const httplib::Request& req, httplib::Response& res,
                const std::string& method, const std::string& json, const std::string& missing) {
  const google::protobuf::MethodDescriptor* m = FindMethod(method);
  if (!m) return SendError(res, grpc::UNIMPLEMENTED, missing);
  auto request = NewMessage(m->input_type());
  google::protobuf::util::JsonParseOptions options;
  if (auto st = google::protobuf::util::JsonStringToMessage(json, request.get(), options); !st.ok())
    return SendError(res, grpc::INVALID_ARGUMENT,
                     absl::StrCat("body: not a ", m->input_type()->full_name(),
                                  " in JSON: ", std::string(st.message())));
  if (req.matches.size() > 1)
    if (const auto* id = m->input_type()->FindFieldByName("job_id"))
      request->GetReflection()->SetString(request.get(), id, req.matches[1]);
  grpc::Slice slice(request->SerializeAsString());
  grpc::ByteBuffer in(&slice, 1), out;
  auto ctx = CallContext(req, 60);
  grpc::GenericStub stub(s.channel);
  std::promise<grpc::Status> done;
  stub.UnaryCall(ctx.get(), absl::StrCat("/nimbus.v1.NimbusService/", method), grpc::StubOptions(),
                 &in, &out, [&done](grpc::Status st) { done.set_value(st); });
  grpc::Status st = done.get_future().get();
  if (!st.ok()) return SendError(res, st);
  std::vector<grpc::Slice> slices;
  std::string bytes;
  if (out.Dump(&slices).ok())
    for (const grpc::Slice& piece : slices)
      bytes.append(reinterpret_cast<const char*>(piece.begin()), piece.size());
  auto response = NewMessage(m->output_type());
  if (!response->ParseFromString(bytes))
    return SendError(res, grpc::INTERNAL, "an answer this server could not read");
  google::protobuf::util::JsonPrintOptions print;
  print.always_print_primitive_fields = true;
  std::string text;
  (void)google::protobuf::util::MessageToJsonString(*response, &text, print);
  res.set_content(text + "\n", "application/json");
}

bool JsonBody(const httplib::Request& req, httplib::Response& res, std::string& json) {
  if (req.get_header_value("Content-Type").rfind("application/json", 0) != 0) {
    SendError(res, grpc::INVALID_ARGUMENT, "Content-Type: send application/json");
    res.status = 415;
    return false;
  }
  json = req.body.empty() ? "{}" : req.body;
  return true;
}

}  // namespace

std::vector<std::string> QueueFeatures() {
  std::vector<std::string> out;
  for (const auto& [method, feature] : {std::pair<const char*, const char*>{"RetryJob", "retry"},
                                        {"SetJobPriority", "priority"},
                                        {"GetJobEvents", "events"},
                                        {"ListWorkers", "workers"}})
    if (FindMethod(method)) out.push_back(feature);
  return out;
}

void RegisterQueue(httplib::Server& server, std::shared_ptr<ApiState> s) {
  const std::string job = "/api/v1/jobs/([^/]+)";
  server.Post(job + "/retry", [s](const httplib::Request& req, httplib::Response& res) {
    std::string json;
    if (JsonBody(req, res, json))
      CallByName(*s, req, res, "RetryJob", json, "this server has no retry");
  });
  server.Post(job + "/priority", [s](const httplib::Request& req, httplib::Response& res) {
    std::string json;
    if (JsonBody(req, res, json))
      CallByName(*s, req, res, "SetJobPriority", json, "this server has no priorities");
  });
  server.Get(job + "/events", [s](const httplib::Request& req, httplib::Response& res) {
    int64_t page_size = 0, after_seq = 0;
    if ((req.has_param("page_size") &&
         !absl::SimpleAtoi(req.get_param_value("page_size"), &page_size)) ||
        (req.has_param("after_seq") &&
         !absl::SimpleAtoi(req.get_param_value("after_seq"), &after_seq)))
      return SendError(res, grpc::INVALID_ARGUMENT, "page_size, after_seq: whole numbers");
    CallByName(*s, req, res, "GetJobEvents",
               absl::StrCat("{\"page_size\":", page_size, ",\"after_seq\":", after_seq, "}"),
               "this server keeps no job event log");
  });
  server.Get("/api/v1/workers", [s](const httplib::Request& req, httplib::Response& res) {
    CallByName(*s, req, res, "ListWorkers", "{}", "no worker registry on this server");
  });
}

}  // namespace nimbus::server::http
