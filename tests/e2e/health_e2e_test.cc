// The standard grpc.health.v1 service answers on a real listening port.
// Debian ships no health.proto, so the messages are encoded by hand: they
// are one field each.
#include <grpcpp/generic/generic_stub.h>
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include "server/server.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

// Calls Health/Check for `service`; returns the ServingStatus number, or -1.
int Check(const std::shared_ptr<grpc::Channel>& channel, const std::string& service) {
  std::string request;
  if (!service.empty()) {
    request.push_back(0x0a);  // field 1, length-delimited
    request.push_back(char(service.size()));
    request += service;
  }
  grpc::Slice slice(request);
  grpc::ByteBuffer request_buf(&slice, 1);
  grpc::GenericStub stub(channel);
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
  grpc::CompletionQueue cq;
  auto call = stub.PrepareUnaryCall(&ctx, "/grpc.health.v1.Health/Check", request_buf, &cq);
  call->StartCall();
  grpc::ByteBuffer response;
  grpc::Status status;
  call->Finish(&response, &status, reinterpret_cast<void*>(1));
  void* tag;
  bool ok;
  cq.Next(&tag, &ok);
  if (!ok || !status.ok()) return -1;
  std::vector<grpc::Slice> slices;
  (void)response.Dump(&slices);
  std::string bytes;
  for (const auto& s : slices) bytes.append(reinterpret_cast<const char*>(s.begin()), s.size());
  // field 1, varint: the status enum (1 = SERVING).
  if (bytes.size() == 2 && bytes[0] == 0x08) return bytes[1];
  return bytes.empty() ? 0 : -1;
}

TEST(HealthE2E, ServingWhileUp) {
  testing::TempDir dir;
  server::ServerOptions o;
  o.listen = "127.0.0.1:0";
  o.data_dir = dir / "data";
  auto server = server::NimbusServer::Start(o);
  ASSERT_TRUE(server.ok()) << server.status();
  ASSERT_GT((*server)->port(), 0);
  auto channel = grpc::CreateChannel("127.0.0.1:" + std::to_string((*server)->port()),
                                     grpc::InsecureChannelCredentials());
  EXPECT_EQ(Check(channel, ""), 1);
  EXPECT_EQ(Check(channel, "nimbus.v1.NimbusService"), 1);
  (*server)->Shutdown();
}

}  // namespace
}  // namespace nimbus
