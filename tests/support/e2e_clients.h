// Clients of a test's own nimbusd, and a small job for them, for
// end-to-end tests. Header-only, so
// the support library does not link the client library.
#pragma once

#include <gtest/gtest.h>

#include <memory>
#include <string>

#include "client/nimbus_client.h"
#include "proto/spec_io.h"
#include "tests/support/test_util.h"

namespace nimbus::testing {

/// A client of `target` that sends `token` (none when empty), once the
/// server answers; a test failure and nullptr when it does not.
inline std::unique_ptr<client::NimbusClient> ConnectAs(const std::string& target,
                                                       const std::string& token) {
  client::ConnectOptions o;
  o.token = token;
  auto c = client::NimbusClient::Connect(target, o);
  EXPECT_TRUE(c.ok()) << c.status();
  if (!c.ok()) return nullptr;
  EXPECT_TRUE((*c)->WaitForReady(20).ok());
  return std::move(*c);
}

/// examples/sierpinski_tetrahedron.json at 16³ and 10⁵ points: a job
/// that finishes in well under a second.
inline v1::JobSpec SmallTetrahedronJob() {
  auto spec = spec::LoadSpecFile(SourcePath("examples/sierpinski_tetrahedron.json"));
  EXPECT_TRUE(spec.ok()) << spec.status();
  if (!spec.ok()) return {};
  spec->mutable_grid()->set_resolution(0, 16);
  spec->mutable_chaos_game()->set_iterations(100'000);
  return *spec;
}

}  // namespace nimbus::testing
