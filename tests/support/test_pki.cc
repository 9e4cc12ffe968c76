#include "tests/support/test_pki.h"

#include <cstdlib>
#include <fstream>
#include <sstream>
#include <string>

#include "absl/strings/str_cat.h"

namespace nimbus::testing {

namespace {

constexpr char kOpenssl[] = "/usr/bin/openssl";

// Runs one openssl command in `dir`, its output going to openssl.log there.
absl::Status Openssl(const std::filesystem::path& dir, const std::string& args) {
  const std::filesystem::path log = dir / "openssl.log";
  const std::string cmd = absl::StrCat("cd '", dir.string(), "' && ", kOpenssl, " ", args, " >>'",
                                       log.string(), "' 2>&1");
  if (std::system(cmd.c_str()) == 0) return absl::OkStatus();
  std::ifstream in(log);
  std::stringstream text;
  text << in.rdbuf();
  return absl::InternalError(absl::StrCat("openssl ", args, " failed:\n", text.str()));
}

absl::Status WriteText(const std::filesystem::path& path, const std::string& text) {
  std::ofstream out(path);
  out << text;
  return out ? absl::OkStatus() : absl::InternalError("cannot write " + path.string());
}

// A CA: self-signed, allowed to sign certificates.
absl::Status MakeCa(const std::filesystem::path& dir, const std::string& name) {
  return Openssl(dir, absl::StrCat("req -x509 -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 "
                                   "-nodes -days 2 -subj /CN=",
                                   name, " -keyout ", name, ".key -out ", name,
                                   ".pem -addext basicConstraints=critical,CA:TRUE "
                                   "-addext keyUsage=critical,keyCertSign,cRLSign"));
}

// A leaf certificate signed by ca.pem, with the extensions in `ext`.
absl::Status MakeLeaf(const std::filesystem::path& dir, const std::string& name,
                      const std::string& cn, const std::string& ext) {
  if (auto s = WriteText(dir / (name + ".ext"), ext); !s.ok()) return s;
  if (auto s = Openssl(dir, absl::StrCat("req -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 "
                                         "-nodes -subj /CN=",
                                         cn, " -keyout ", name, ".key -out ", name, ".csr"));
      !s.ok())
    return s;
  return Openssl(dir, absl::StrCat("x509 -req -in ", name,
                                   ".csr -CA ca.pem -CAkey ca.key "
                                   "-CAcreateserial -days 2 -out ",
                                   name, ".pem -extfile ", name, ".ext"));
}

}  // namespace

absl::StatusOr<TestPki> MakeTestPki(const std::filesystem::path& dir) {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (auto s = MakeCa(dir, "ca"); !s.ok()) return s;
  if (auto s = MakeCa(dir, "other_ca"); !s.ok()) return s;
  if (auto s = MakeLeaf(dir, "server", "localhost",
                        "subjectAltName=IP:127.0.0.1,DNS:localhost\n"
                        "extendedKeyUsage=serverAuth\n");
      !s.ok())
    return s;
  if (auto s = MakeLeaf(dir, "client", "test-client", "extendedKeyUsage=clientAuth\n"); !s.ok())
    return s;
  TestPki pki;
  pki.ca_cert = dir / "ca.pem";
  pki.other_ca_cert = dir / "other_ca.pem";
  pki.server_cert = dir / "server.pem";
  pki.server_key = dir / "server.key";
  pki.client_cert = dir / "client.pem";
  pki.client_key = dir / "client.key";
  return pki;
}

}  // namespace nimbus::testing
