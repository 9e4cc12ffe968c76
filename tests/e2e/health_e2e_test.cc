// The standard grpc.health.v1 service answers on a real listening port.
// Debian ships no health.proto, so the messages are encoded by hand: they
// are one field each.
#include <grpcpp/generic/generic_stub.h>
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include "client/nimbus_client.h"
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

// Also `nimbus health` (NimbusClient::Health): it reads the same answers as
// the hand-encoded call, and tells an unknown service apart.
TEST(HealthE2E, ServingWhileUp) {
  testing::TempDir dir;
  server::ServerOptions o;
  o.listen = "127.0.0.1:0";
  o.data_dir = dir / "data";
  auto server = server::NimbusServer::Start(o);
  ASSERT_TRUE(server.ok()) << server.status();
  ASSERT_GT((*server)->port(), 0);
  const std::string target = "127.0.0.1:" + std::to_string((*server)->port());
  auto channel = grpc::CreateChannel(target, grpc::InsecureChannelCredentials());
  EXPECT_EQ(Check(channel, ""), 1);
  EXPECT_EQ(Check(channel, "nimbus.v1.NimbusService"), 1);
  auto client = client::NimbusClient::Connect(target);
  for (const std::string service : {"", "nimbus.v1.NimbusService"}) {
    auto status = client->Health(service, 10);
    ASSERT_TRUE(status.ok()) << service << ": " << status.status();
    EXPECT_EQ(*status, 1) << service;
  }
  EXPECT_EQ(client->Health("no.such.Service", 10).status().code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(client->Health(std::string(200, 's'), 10).status().code(),
            absl::StatusCode::kInvalidArgument);
  (*server)->Shutdown();
}

}  // namespace
}  // namespace nimbus
