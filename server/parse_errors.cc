#include "server/parse_errors.h"

#include <string>

#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/strip.h"
#include "google/protobuf/descriptor.h"

namespace nimbus::server {

namespace {

constexpr char kServicePrefix[] = "/nimbus.v1.NimbusService/";

using grpc::experimental::InterceptionHookPoints;

// "/nimbus.v1.NimbusService/SubmitJob" names a method the service has; an
// unknown method's UNIMPLEMENTED is left as it is.
bool IsServiceMethod(absl::string_view method) {
  if (!absl::ConsumePrefix(&method, kServicePrefix)) return false;
  const auto* service = google::protobuf::DescriptorPool::generated_pool()->FindServiceByName(
      "nimbus.v1.NimbusService");
  return service != nullptr && service->FindMethodByName(std::string(method)) != nullptr;
}

class UndecodableRequest : public grpc::experimental::Interceptor {
 public:
  explicit UndecodableRequest(std::string method) : method_(std::move(method)) {}

  void Intercept(grpc::experimental::InterceptorBatchMethods* methods) override {
    if (methods->QueryInterceptionHookPoint(InterceptionHookPoints::PRE_SEND_STATUS)) {
      const grpc::Status st = methods->GetSendStatus();
      if (st.error_code() == grpc::StatusCode::UNIMPLEMENTED && st.error_message().empty())
        methods->ModifySendStatus(
            grpc::Status(grpc::StatusCode::INVALID_ARGUMENT, UndecodableRequestMessage(method_)));
    }
    methods->Proceed();
  }

 private:
  std::string method_;
};

class UndecodableRequestFactory : public grpc::experimental::ServerInterceptorFactoryInterface {
 public:
  grpc::experimental::Interceptor* CreateServerInterceptor(
      grpc::experimental::ServerRpcInfo* info) override {
    const char* method = info->method();
    if (method == nullptr || !IsServiceMethod(method)) return nullptr;
    return new UndecodableRequest(method);
  }
};

}  // namespace

std::string UndecodableRequestMessage(const std::string& method) {
  absl::string_view name = method;
  absl::ConsumePrefix(&name, kServicePrefix);
  return absl::StrCat("the ", name,
                      " request could not be parsed: its bytes are not a valid nimbus.v1 ", name,
                      "Request (malformed protobuf, a string that is not UTF-8, or messages "
                      "nested deeper than 100 levels)");
}

std::vector<std::unique_ptr<grpc::experimental::ServerInterceptorFactoryInterface>>
UndecodableRequestInterceptors() {
  std::vector<std::unique_ptr<grpc::experimental::ServerInterceptorFactoryInterface>> out;
  out.push_back(std::make_unique<UndecodableRequestFactory>());
  return out;
}

}  // namespace nimbus::server
