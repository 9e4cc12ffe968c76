#include "server/bounded_text.h"

#include "absl/strings/str_cat.h"

namespace nimbus::server {

namespace {

// Length of the valid UTF-8 sequence starting at `s[i]`, or 0 when the bytes
// there are not one (overlong forms and surrogates included).
size_t Utf8Length(absl::string_view s, size_t i) {
  const auto b = [&](size_t k) { return static_cast<unsigned char>(s[k]); };
  const unsigned char c = b(i);
  if (c < 0x80) return 1;
  size_t n = 0;
  uint32_t cp = 0;
  if (c >= 0xc2 && c <= 0xdf)
    n = 2, cp = c & 0x1f;
  else if (c >= 0xe0 && c <= 0xef)
    n = 3, cp = c & 0x0f;
  else if (c >= 0xf0 && c <= 0xf4)
    n = 4, cp = c & 0x07;
  else
    return 0;
  if (i + n > s.size()) return 0;
  for (size_t k = 1; k < n; ++k) {
    if ((b(i + k) & 0xc0) != 0x80) return 0;
    cp = (cp << 6) | (b(i + k) & 0x3f);
  }
  if ((n == 3 && cp < 0x800) || (n == 4 && (cp < 0x10000 || cp > 0x10ffff))) return 0;
  if (cp >= 0xd800 && cp <= 0xdfff) return 0;
  return n;
}

// Appends the cleaned characters of `text` until `max_bytes` are out.
// Returns whether all of `text` fitted.
bool AppendClean(absl::string_view text, size_t max_bytes, std::string& out) {
  for (size_t i = 0; i < text.size();) {
    size_t n = Utf8Length(text, i);
    const unsigned char c = static_cast<unsigned char>(text[i]);
    const bool control = n == 1 && ((c < 0x20 && c != '\n' && c != '\t') || c == 0x7f);
    const size_t out_len = (n == 0 || control) ? 1 : n;
    if (out.size() + out_len > max_bytes) return false;
    if (n == 0 || control) {
      out.push_back('?');
      n = 1;
    } else {
      out.append(text.data() + i, n);
    }
    i += n;
  }
  return true;
}

}  // namespace

std::string BoundText(absl::string_view text, size_t max_bytes) {
  std::string out;
  out.reserve(std::min(text.size(), max_bytes) + 48);
  if (AppendClean(text, max_bytes, out)) return out;
  absl::StrAppend(&out, "\xe2\x80\xa6 [truncated, ", text.size(), " bytes]");
  return out;
}

std::string EchoId(absl::string_view id) {
  std::string out;
  if (!AppendClean(id, kMaxEchoedIdBytes, out)) out += "\xe2\x80\xa6";
  return out;
}

}  // namespace nimbus::server
