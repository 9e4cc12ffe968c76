// PEM files for TLS, checked before gRPC sees them, so that a bad file is
// refused naming the file and what is wrong with it instead of the
// listener failing without a reason.
//
//   auto st = CheckTlsKeyPair({"--tls-cert", cert_path, cert_pem},
//                             {"--tls-key", key_path, key_pem});
//   // "--tls-cert /etc/nimbus/server.pem: no PEM certificate in it (...)"
#pragma once

#include <string>

#include "absl/status/status.h"

namespace nimbus::server {

/// A PEM file's text, the flag that named it and its path (for messages).
struct PemFile {
  std::string flag;
  std::string path;
  std::string pem;
};

/// OK when `certs` holds one or more PEM certificates and nothing else that
/// fails to parse; INVALID_ARGUMENT "FLAG PATH: why" otherwise.
absl::Status CheckPemCertificates(const PemFile& certs);

/// CheckPemCertificates of `cert`, and `key` is a PEM private key that
/// belongs to the first certificate of `cert`.
absl::Status CheckTlsKeyPair(const PemFile& cert, const PemFile& key);

}  // namespace nimbus::server
