#include "server/tls_files.h"

#include <openssl/bio.h>
#include <openssl/err.h>
#include <openssl/evp.h>
#include <openssl/pem.h>
#include <openssl/x509.h>

#include <memory>

#include "absl/strings/str_cat.h"

namespace nimbus::server {

namespace {

struct BioFree {
  void operator()(BIO* b) const { BIO_free(b); }
};
struct X509Free {
  void operator()(X509* x) const { X509_free(x); }
};
struct KeyFree {
  void operator()(EVP_PKEY* k) const { EVP_PKEY_free(k); }
};
using Bio = std::unique_ptr<BIO, BioFree>;
using Cert = std::unique_ptr<X509, X509Free>;
using Key = std::unique_ptr<EVP_PKEY, KeyFree>;

Bio ReadOnly(const std::string& text) {
  return Bio(BIO_new_mem_buf(text.data(), static_cast<int>(text.size())));
}

// OpenSSL's reason for the newest error on this thread; clears the queue.
std::string OpenSslReason() {
  const unsigned long e = ERR_peek_last_error();
  const char* reason = e == 0 ? nullptr : ERR_reason_error_string(e);
  ERR_clear_error();
  return reason == nullptr ? "unreadable" : reason;
}

absl::Status Bad(const PemFile& f, const std::string& why) {
  return absl::InvalidArgumentError(absl::StrCat(f.flag, " ", f.path, ": ", why));
}

// The first certificate of `f`, after checking that every one parses.
absl::Status ReadCertificates(const PemFile& f, Cert* first) {
  ERR_clear_error();
  Bio bio = ReadOnly(f.pem);
  int count = 0;
  while (Cert c{PEM_read_bio_X509(bio.get(), nullptr, nullptr, nullptr)}) {
    if (count++ == 0 && first != nullptr) *first = std::move(c);
  }
  // Reading stops at the end of the text (no start line found) or at a
  // block that does not parse; only the first is expected.
  const unsigned long e = ERR_peek_last_error();
  const bool at_end = ERR_GET_LIB(e) == ERR_LIB_PEM && ERR_GET_REASON(e) == PEM_R_NO_START_LINE;
  if (e != 0 && !at_end)
    return Bad(f, absl::StrCat("certificate ", count + 1, " is not valid: ", OpenSslReason()));
  ERR_clear_error();
  if (count == 0)
    return Bad(f, "no PEM certificate in it (expected a -----BEGIN CERTIFICATE----- block)");
  return absl::OkStatus();
}

}  // namespace

absl::Status CheckPemCertificates(const PemFile& certs) { return ReadCertificates(certs, nullptr); }

absl::Status CheckTlsKeyPair(const PemFile& cert, const PemFile& key) {
  Cert first;
  if (absl::Status st = ReadCertificates(cert, &first); !st.ok()) return st;
  ERR_clear_error();
  Bio bio = ReadOnly(key.pem);
  Key pkey{PEM_read_bio_PrivateKey(bio.get(), nullptr, nullptr, nullptr)};
  if (pkey == nullptr)
    return Bad(key, absl::StrCat("not a PEM private key without a passphrase: ", OpenSslReason()));
  if (X509_check_private_key(first.get(), pkey.get()) != 1) {
    ERR_clear_error();
    return Bad(key,
               absl::StrCat("is not the key of the certificate in ", cert.flag, " ", cert.path));
  }
  return absl::OkStatus();
}

}  // namespace nimbus::server
