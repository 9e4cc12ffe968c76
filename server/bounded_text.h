// Bounds on the strings the server stores, logs and sends. A hostile or
// broken input (a 1 GB parser message, a 10 MB name, a 100 KB id) must not
// grow the database, the logs or a response without limit.
#pragma once

#include <cstddef>
#include <string>

#include "absl/strings/string_view.h"

namespace nimbus::server {

/// Longest job name accepted (bytes).
inline constexpr size_t kMaxJobNameBytes = 128;
/// Longest error message stored or sent for a job.
inline constexpr size_t kMaxErrorBytes = 4096;
/// Longest warnings text (all warnings of a job together).
inline constexpr size_t kMaxWarningsBytes = 16384;
/// Longest client-supplied id or token echoed back in a message.
inline constexpr size_t kMaxEchoedIdBytes = 64;

/// `text` as valid UTF-8 (bad bytes and control characters other than
/// newline and tab become '?'), cut on a character boundary to at most
/// `max_bytes` plus a marker "… [truncated, N bytes]" naming the original
/// size when it was longer.
std::string BoundText(absl::string_view text, size_t max_bytes);

/// A client-supplied id or token for an error message: cleaned like
/// BoundText, at most kMaxEchoedIdBytes and "…" when cut.
std::string EchoId(absl::string_view id);

}  // namespace nimbus::server
