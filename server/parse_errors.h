// Requests gRPC could not decode, answered as what they are.
//
//   builder.experimental().SetInterceptorCreators(UndecodableRequestInterceptors());
#pragma once

#include <grpcpp/support/server_interceptor.h>

#include <memory>
#include <vector>

namespace nimbus::server {

/// The words a caller gets when its request to `method` (a full gRPC
/// method name, "/nimbus.v1.NimbusService/SubmitJob") could not be parsed.
std::string UndecodableRequestMessage(const std::string& method);

/// @brief Interceptors for a ServerBuilder: a call to a NimbusService
/// method whose request message gRPC could not parse (bytes that are not
/// the message, a string field that is not UTF-8, nesting deeper than 100
/// levels) ends INVALID_ARGUMENT with UndecodableRequestMessage instead of
/// the library's bare UNIMPLEMENTED. gRPC's callback API answers exactly
/// those calls UNIMPLEMENTED with no message, before the service sees them;
/// the service itself never answers UNIMPLEMENTED, and unknown methods keep
/// their UNIMPLEMENTED.
std::vector<std::unique_ptr<grpc::experimental::ServerInterceptorFactoryInterface>>
UndecodableRequestInterceptors();

}  // namespace nimbus::server
