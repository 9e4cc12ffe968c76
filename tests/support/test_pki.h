// @brief A throw-away public key infrastructure for TLS tests: a CA, a
// server certificate for 127.0.0.1 and localhost, and a client certificate,
// made with the openssl command-line tool into a folder the test owns.
#pragma once

#include <filesystem>

#include "absl/status/statusor.h"

namespace nimbus::testing {

struct TestPki {
  std::filesystem::path ca_cert;
  std::filesystem::path server_cert, server_key;
  /// Signed by the CA, for mutual TLS; its subject CN is "test-client".
  std::filesystem::path client_cert, client_key;
  /// A second CA that signed nothing the server trusts.
  std::filesystem::path other_ca_cert;
};

/// Writes the PEM files into `dir` (P-256 keys, valid for two days).
/// INTERNAL with openssl's output when a step fails.
absl::StatusOr<TestPki> MakeTestPki(const std::filesystem::path& dir);

}  // namespace nimbus::testing
