// The fixture of the e2e tests of a job kind: a real nimbusd on loopback
// (one worker, two threads per job, warnings only) in a temporary data
// folder, and a client connected to it; plus loading an example spec.
//
//   class FernE2E : public testing::NimbusdTest {};
//   TEST_F(FernE2E, Runs) { client_->Submit(testing::LoadExample("tree.json")); }
#pragma once

#include <gtest/gtest.h>

#include <memory>
#include <string>

#include "client/nimbus_client.h"
#include "proto/spec_io.h"
#include "tests/support/nimbusd_process.h"
#include "tests/support/test_util.h"

namespace nimbus::testing {

/// examples/NAME parsed; a failure is reported to the running test.
inline v1::JobSpec LoadExample(const std::string& name) {
  auto spec = spec::LoadSpecFile(SourcePath("examples/" + name));
  EXPECT_TRUE(spec.ok()) << spec.status();
  return spec.ok() ? *spec : v1::JobSpec();
}

class NimbusdTest : public ::testing::Test {
 protected:
  void SetUp() override {
    absl::Status s = server_.Start();
    ASSERT_TRUE(s.ok()) << s;
    client_ = client::NimbusClient::Connect(server_.target());
    ASSERT_TRUE(client_->WaitForReady(20).ok()) << "nimbusd did not answer";
  }

  TempDir dir_;
  NimbusdProcess server_{
      dir_ / "data", {"--workers", "1", "--threads-per-job", "2", "--log-level", "warn"}};
  std::unique_ptr<client::NimbusClient> client_;
};

}  // namespace nimbus::testing
