// @brief Who is calling: bearer tokens mapped to principals, the admin role,
// and the rule that a server reachable from other hosts needs them. gRPC
// metadata is handed in as plain strings so this stays free of gRPC types.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"

namespace nimbus::server {

/// A caller as the service sees it. Jobs, assets and results belong to a
/// principal; an admin sees and may act on everyone's.
struct Principal {
  std::string name;
  bool admin = false;
};

/// Limits per principal; 0 means none.
struct Quotas {
  /// QUEUED plus RUNNING jobs.
  uint64_t jobs = 0;
  /// Bytes of stored assets the principal uploaded.
  uint64_t asset_bytes = 0;
  /// Bytes of kept (unexpired) results.
  uint64_t result_bytes = 0;
};

/// The principal of a server without tokens (the embedded server, a
/// loopback bind, or --insecure): one anonymous admin.
Principal AnonymousPrincipal();

/// @brief Tokens and their principals. Only SHA-256 digests of the tokens
/// are kept, and a presented token is compared with every entry in constant
/// time, so neither memory nor timing gives a token away.
class TokenTable {
 public:
  /// Parses lines `TOKEN PRINCIPAL [admin]`; blank lines and lines starting
  /// with '#' are skipped. `source` names the text in errors (never a token).
  static absl::StatusOr<TokenTable> Parse(absl::string_view text, const std::string& source);

  bool empty() const { return entries_.empty(); }
  size_t size() const { return entries_.size(); }
  /// The principal of `authorization` ("Bearer TOKEN"), or UNAUTHENTICATED
  /// saying what is missing or wrong (never echoing the token). An empty
  /// table accepts every call as AnonymousPrincipal().
  absl::StatusOr<Principal> Authenticate(std::optional<absl::string_view> authorization) const;

 private:
  struct Entry {
    std::string digest;  // hex SHA-256 of the token
    Principal principal;
  };
  std::vector<Entry> entries_;
};

/// The text of a tokens file. FAILED_PRECONDITION when group or others may
/// access it: a readable token file is a leaked server.
absl::StatusOr<std::string> ReadTokensFile(const std::string& path);

/// True for "127.0.0.1:50051", "localhost:0", "[::1]:80" and other
/// addresses only this host can reach.
bool IsLoopbackListen(const std::string& listen);

/// Two strings of equal length compared without an early exit.
bool ConstantTimeEquals(absl::string_view a, absl::string_view b);

}  // namespace nimbus::server
