#include "server/auth.h"

#include <sys/stat.h>

#include <fstream>
#include <sstream>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "core/base/sha256.h"

namespace nimbus::server {

namespace {

constexpr absl::string_view kBearer = "Bearer ";
// Shorter tokens can be guessed; the operator guide suggests 32 random bytes.
constexpr size_t kMinTokenBytes = 16;

}  // namespace

Principal AnonymousPrincipal() { return Principal{"anonymous", true}; }

bool ConstantTimeEquals(absl::string_view a, absl::string_view b) {
  if (a.size() != b.size()) return false;
  unsigned char diff = 0;
  for (size_t i = 0; i < a.size(); ++i) diff |= static_cast<unsigned char>(a[i] ^ b[i]);
  return diff == 0;
}

absl::StatusOr<TokenTable> TokenTable::Parse(absl::string_view text, const std::string& source) {
  TokenTable table;
  int line_no = 0;
  for (absl::string_view line : absl::StrSplit(text, absl::ByAnyChar("\n;"))) {
    ++line_no;
    line = absl::StripAsciiWhitespace(line);
    if (line.empty() || line.front() == '#') continue;
    std::vector<absl::string_view> words =
        absl::StrSplit(line, absl::ByAnyChar(" \t"), absl::SkipWhitespace());
    const std::string where = absl::StrCat(source, " entry ", line_no);
    if (words.size() < 2 || words.size() > 3 || (words.size() == 3 && words[2] != "admin"))
      return absl::InvalidArgumentError(
          absl::StrCat(where, ": expected 'TOKEN PRINCIPAL' or 'TOKEN PRINCIPAL admin'"));
    if (words[0].size() < kMinTokenBytes)
      return absl::InvalidArgumentError(
          absl::StrCat(where, ": token is shorter than ", kMinTokenBytes, " characters"));
    Entry e{Sha256Hex(std::string(words[0])), Principal{std::string(words[1]), words.size() == 3}};
    for (const Entry& other : table.entries_)
      if (other.digest == e.digest)
        return absl::InvalidArgumentError(absl::StrCat(where, ": token used twice"));
    table.entries_.push_back(std::move(e));
  }
  if (table.entries_.empty())
    return absl::InvalidArgumentError(absl::StrCat(source, ": no tokens"));
  return table;
}

absl::StatusOr<std::string> ReadTokensFile(const std::string& path) {
  struct stat st;
  if (::stat(path.c_str(), &st) != 0)
    return absl::NotFoundError(absl::StrCat("--auth-tokens ", path, ": cannot read the file"));
  if (st.st_mode & (S_IRWXG | S_IRWXO))
    return absl::FailedPreconditionError(
        absl::StrFormat("--auth-tokens %s: group or others may access it (mode %03o); "
                        "chmod 600 it",
                        path, st.st_mode & 0777));
  std::ifstream in(path);
  std::stringstream text;
  text << in.rdbuf();
  if (!in) return absl::NotFoundError(absl::StrCat("--auth-tokens ", path, ": cannot read"));
  return text.str();
}

absl::StatusOr<Principal> TokenTable::Authenticate(
    std::optional<absl::string_view> authorization) const {
  if (entries_.empty()) return AnonymousPrincipal();
  if (!authorization.has_value())
    return absl::UnauthenticatedError(
        "this server requires a token: send 'authorization: Bearer TOKEN' (nimbus --token or "
        "$NIMBUS_TOKEN)");
  if (!absl::StartsWith(*authorization, kBearer))
    return absl::UnauthenticatedError("authorization metadata must be 'Bearer TOKEN'");
  const std::string digest = Sha256Hex(std::string(authorization->substr(kBearer.size())));
  // Every entry is compared, found or not, so timing says nothing.
  const Principal* found = nullptr;
  for (const Entry& e : entries_)
    if (ConstantTimeEquals(e.digest, digest)) found = &e.principal;
  if (found == nullptr) return absl::UnauthenticatedError("unknown token");
  return *found;
}

bool IsLoopbackListen(const std::string& listen) {
  if (absl::StartsWith(listen, "unix:")) return true;  // a local socket file
  const size_t colon = listen.rfind(':');
  std::string host = listen.substr(0, colon == std::string::npos ? listen.size() : colon);
  if (host.size() >= 2 && host.front() == '[' && host.back() == ']')
    host = host.substr(1, host.size() - 2);
  host = absl::AsciiStrToLower(host);
  return host == "localhost" || host == "::1" || absl::StartsWith(host, "127.");
}

}  // namespace nimbus::server
