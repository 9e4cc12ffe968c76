// Security against a real nimbusd: TLS with a CA the test makes (and mutual
// TLS), bearer tokens, the rule that a server beyond loopback needs them,
// ownership of jobs, results and assets, quotas, and retention with pins
// and deletes.
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <sys/wait.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <sstream>
#include <thread>

#include "absl/strings/str_cat.h"
#include "client/nimbus_client.h"
#include "core/base/sha256.h"
#include "proto/asset_paths.h"
#include "proto/spec_io.h"
#include "tests/support/e2e_clients.h"
#include "tests/support/nimbusd_process.h"
#include "tests/support/test_pki.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

using client::ConnectOptions;
using client::NimbusClient;
using ::testing::HasSubstr;

// Tokens of the test's principals; the file gives root the admin role.
constexpr char kAlice[] = "alice-token-0123456789abcdef";
constexpr char kBob[] = "bob-token-0123456789abcdef00";
constexpr char kRoot[] = "root-token-0123456789abcdef0";

v1::JobSpec SmallJob() { return testing::SmallTetrahedronJob(); }

// A job that runs until cancelled.
v1::JobSpec EndlessJob() {
  v1::JobSpec spec = SmallJob();
  spec.mutable_chaos_game()->set_iterations(uint64_t{1} << 38);
  return spec;
}

std::string ReadAll(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

class SecurityE2E : public ::testing::Test {
 protected:
  // Writes the tokens file with `mode` and returns its path.
  std::filesystem::path TokensFile(mode_t mode = 0600) {
    const std::filesystem::path path = dir_ / "tokens";
    std::ofstream(path) << "# token principal [admin]\n"
                        << kAlice << " alice\n"
                        << kBob << " bob\n"
                        << kRoot << " root admin\n";
    ::chmod(path.c_str(), mode);
    return path;
  }

  // Starts nimbusd with tokens and `more` flags.
  void StartWithTokens(std::vector<std::string> more = {}) {
    std::vector<std::string> args = {"--workers",           "1",
                                     "--threads-per-job",   "2",
                                     "--log-level",         "warn",
                                     "--min-free-disk-mib", "0",
                                     "--auth-tokens",       TokensFile().string()};
    args.insert(args.end(), more.begin(), more.end());
    server_.set_args(args);
    const absl::Status s = server_.Start();
    ASSERT_TRUE(s.ok()) << s;
  }

  std::unique_ptr<NimbusClient> As(const std::string& token) {
    return testing::ConnectAs(server_.target(), token);
  }

  // Submits and watches to the end.
  v1::Job Run(NimbusClient& c, const v1::JobSpec& spec) {
    auto job = c.Submit(spec);
    EXPECT_TRUE(job.ok()) << job.status();
    if (!job.ok()) return {};
    auto done = c.Watch(job->id(), {}, [](const v1::WatchJobResponse&) {});
    EXPECT_TRUE(done.ok()) << done.status();
    if (!done.ok()) return {};
    EXPECT_EQ(done->state(), v1::JOB_STATE_SUCCEEDED) << done->error();
    return *done;
  }

  std::filesystem::path ResultPath(const std::string& job_id) {
    return dir_ / "data" / "results" / (job_id + ".vdb");
  }

  testing::TempDir dir_;
  testing::NimbusdProcess server_{dir_ / "data"};
};

TEST_F(SecurityE2E, TlsRoundTripWithATestCa) {
  auto pki = testing::MakeTestPki(dir_ / "pki");
  ASSERT_TRUE(pki.ok()) << pki.status();
  server_.set_args({"--workers", "1", "--log-level", "warn", "--min-free-disk-mib", "0",
                    "--tls-cert", pki->server_cert.string(), "--tls-key",
                    pki->server_key.string()});
  ASSERT_TRUE(server_.Start().ok());

  ConnectOptions tls;
  tls.tls_ca_file = pki->ca_cert.string();
  auto c = NimbusClient::Connect(server_.target(), tls);
  ASSERT_TRUE(c.ok()) << c.status();
  ASSERT_TRUE((*c)->WaitForReady(20).ok());
  const v1::Job done = Run(**c, SmallJob());
  const std::filesystem::path out = dir_ / "out.vdb";
  ASSERT_TRUE((*c)->Fetch(done.id(), out).ok());
  EXPECT_EQ(*Sha256File(out), done.result().sha256());
  EXPECT_EQ(*Sha256File(out), *Sha256File(ResultPath(done.id())));

  // Plaintext, or a CA that did not sign the server, never gets an answer.
  auto plain = NimbusClient::Connect(server_.target());
  EXPECT_FALSE(plain->WaitForReady(2).ok());
  ConnectOptions wrong_ca;
  wrong_ca.tls_ca_file = pki->other_ca_cert.string();
  auto stranger = NimbusClient::Connect(server_.target(), wrong_ca);
  ASSERT_TRUE(stranger.ok());
  EXPECT_EQ((*stranger)->Get(done.id()).status().code(), absl::StatusCode::kUnavailable);

  // A missing PEM file is named.
  ConnectOptions missing;
  missing.tls_ca_file = (dir_ / "nope.pem").string();
  auto bad = NimbusClient::Connect(server_.target(), missing);
  EXPECT_EQ(bad.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(bad.status().message(), HasSubstr("nope.pem"));
}

TEST_F(SecurityE2E, MutualTlsRefusesAClientWithoutACertificate) {
  auto pki = testing::MakeTestPki(dir_ / "pki");
  ASSERT_TRUE(pki.ok()) << pki.status();
  server_.set_args({"--log-level", "warn", "--min-free-disk-mib", "0", "--tls-cert",
                    pki->server_cert.string(), "--tls-key", pki->server_key.string(),
                    "--tls-client-ca", pki->ca_cert.string()});
  ASSERT_TRUE(server_.Start().ok());

  ConnectOptions no_cert;
  no_cert.tls_ca_file = pki->ca_cert.string();
  auto anonymous = NimbusClient::Connect(server_.target(), no_cert);
  ASSERT_TRUE(anonymous.ok());
  EXPECT_EQ((*anonymous)->Get("j-none").status().code(), absl::StatusCode::kUnavailable);

  ConnectOptions with_cert = no_cert;
  with_cert.tls_cert_file = pki->client_cert.string();
  with_cert.tls_key_file = pki->client_key.string();
  auto known = NimbusClient::Connect(server_.target(), with_cert);
  ASSERT_TRUE(known.ok());
  ASSERT_TRUE((*known)->WaitForReady(20).ok());
  // The call reaches the service: an unknown job, not a transport error.
  EXPECT_EQ((*known)->Get("j-none").status().code(), absl::StatusCode::kNotFound);
}

TEST_F(SecurityE2E, MissingOrWrongTokenIsUnauthenticated) {
  StartWithTokens();
  auto none = As("");
  auto job = none->Submit(SmallJob());
  EXPECT_EQ(job.status().code(), absl::StatusCode::kUnauthenticated);
  EXPECT_THAT(job.status().message(), HasSubstr("requires a token"));
  auto wrong = As("not-a-token-of-this-server");
  EXPECT_EQ(wrong->Get("j-x").status().code(), absl::StatusCode::kUnauthenticated);
  EXPECT_THAT(wrong->Get("j-x").status().message(), HasSubstr("unknown token"));
  // Streams too: watch, fetch and upload.
  EXPECT_EQ(wrong->Fetch("j-x", dir_ / "x.vdb").code(), absl::StatusCode::kUnauthenticated);
  EXPECT_EQ(wrong->Watch("j-x", {}, [](const v1::WatchJobResponse&) {}).status().code(),
            absl::StatusCode::kUnauthenticated);
  EXPECT_EQ(wrong->UploadBytes("a.bin", "abc", Sha256Hex("abc"), 3).status().code(),
            absl::StatusCode::kUnauthenticated);
  v1::ListJobsRequest list;
  EXPECT_EQ(none->List(list).status().code(), absl::StatusCode::kUnauthenticated);
  // The right token works, and the server never logged one.
  EXPECT_TRUE(As(kAlice)->List(list).ok());
}

TEST_F(SecurityE2E, ATokensFileOthersMayReadIsRefused) {
  server_.set_log_file(dir_ / "nimbusd.log");
  server_.set_args({"--auth-tokens", TokensFile(0644).string()});
  EXPECT_FALSE(server_.Start().ok());
  EXPECT_THAT(ReadAll(dir_ / "nimbusd.log"), HasSubstr("chmod 600"));
}

TEST_F(SecurityE2E, BeyondLoopbackWithoutTokensNeedsInsecure) {
  server_.set_log_file(dir_ / "nimbusd.log");
  server_.set_listen_host("0.0.0.0");
  server_.set_args({"--min-free-disk-mib", "0"});
  EXPECT_FALSE(server_.Start().ok());
  const std::string log = ReadAll(dir_ / "nimbusd.log");
  EXPECT_THAT(log, HasSubstr("refusing to listen on 0.0.0.0:0 without authentication"));
  EXPECT_THAT(log, HasSubstr("--insecure"));

  server_.set_args({"--min-free-disk-mib", "0", "--insecure"});
  ASSERT_TRUE(server_.Start().ok());
  auto c = NimbusClient::Connect(server_.target());
  ASSERT_TRUE(c->WaitForReady(20).ok());
  EXPECT_EQ(c->Get("j-none").status().code(), absl::StatusCode::kNotFound);
  server_.Kill();

  // With tokens no flag is needed.
  server_.set_args({"--min-free-disk-mib", "0", "--auth-tokens", TokensFile().string()});
  ASSERT_TRUE(server_.Start().ok());
  EXPECT_TRUE(As(kBob)->List(v1::ListJobsRequest()).ok());
}

TEST_F(SecurityE2E, AnotherPrincipalsJobIsNotFoundAndAdminSeesIt) {
  StartWithTokens();
  auto alice = As(kAlice), bob = As(kBob), root = As(kRoot);
  const v1::Job job = Run(*alice, SmallJob());
  EXPECT_EQ(job.owner(), "alice");

  const auto not_found = [&](const absl::Status& s) {
    EXPECT_EQ(s.code(), absl::StatusCode::kNotFound) << s;
    EXPECT_THAT(s.message(), HasSubstr(job.id()));
  };
  not_found(bob->Get(job.id()).status());
  not_found(bob->Cancel(job.id()).status());
  not_found(bob->Fetch(job.id(), dir_ / "stolen.vdb"));
  not_found(bob->Watch(job.id(), {}, [](const v1::WatchJobResponse&) {}).status());
  not_found(bob->Pin(job.id(), true).status());
  not_found(bob->Delete(job.id()).status());
  // Unknown ids read the same, so ids cannot be probed.
  EXPECT_EQ(bob->Get("j-0000000000000000").status().message(),
            "job \"j-0000000000000000\" not found");
  EXPECT_EQ(bob->Get(job.id()).status().message(),
            absl::StrCat("job \"", job.id(), "\" not found"));
  auto bobs = bob->List(v1::ListJobsRequest());
  ASSERT_TRUE(bobs.ok());
  EXPECT_EQ(bobs->jobs_size(), 0);

  auto alices = alice->List(v1::ListJobsRequest());
  ASSERT_TRUE(alices.ok());
  ASSERT_EQ(alices->jobs_size(), 1);
  EXPECT_EQ(alices->jobs(0).id(), job.id());
  auto seen = root->Get(job.id());
  ASSERT_TRUE(seen.ok()) << seen.status();
  EXPECT_EQ(seen->owner(), "alice");
  ASSERT_TRUE(root->Fetch(job.id(), dir_ / "admin.vdb").ok());
  EXPECT_EQ(*Sha256File(dir_ / "admin.vdb"), job.result().sha256());

  // Assets: bob cannot build on alice's upload, named by field.
  const std::string cow = ReadAll(testing::SourcePath("examples/meshes/cow.obj"));
  ASSERT_TRUE(alice->UploadBytes("cow.obj", cow, Sha256Hex(cow), cow.size()).ok());
  auto spec = spec::LoadSpecFile(testing::SourcePath("examples/cow_cloud.json"));
  ASSERT_TRUE(spec.ok());
  spec->mutable_grid()->set_resolution(0, 16);
  spec::ForEachAsset(*spec,
                     [&](const std::string&, v1::Asset& a) { a.set_sha256(Sha256Hex(cow)); });
  auto refused = bob->Submit(*spec);
  EXPECT_EQ(refused.status().code(), absl::StatusCode::kNotFound) << refused.status();
  EXPECT_THAT(refused.status().message(),
              HasSubstr("set_ifs.maps[0].condensation.mesh.asset.sha256: no uploaded asset"));
  // Once bob uploads the same bytes, they are his too (stored once); the
  // answer is a first upload's, so it tells him nothing of alice's.
  auto again = bob->UploadBytes("cow.obj", cow, Sha256Hex(cow), cow.size());
  ASSERT_TRUE(again.ok());
  EXPECT_FALSE(again->already_present());
  auto accepted = bob->Submit(*spec);
  ASSERT_TRUE(accepted.ok()) << accepted.status();
  EXPECT_TRUE(bob->Cancel(accepted->id()).ok());
}

TEST_F(SecurityE2E, QuotasRefuseWithTheNumbers) {
  StartWithTokens(
      {"--quota-jobs", "1", "--quota-asset-bytes", "1000", "--quota-result-bytes", "1"});
  auto alice = As(kAlice), bob = As(kBob);
  auto endless = alice->Submit(EndlessJob());
  ASSERT_TRUE(endless.ok()) << endless.status();
  auto second = alice->Submit(SmallJob());
  EXPECT_EQ(second.status().code(), absl::StatusCode::kResourceExhausted);
  EXPECT_THAT(second.status().message(),
              HasSubstr("job quota: principal alice has 1 queued or running jobs, the quota is 1"));
  // A running job cannot be deleted; cancelled, it frees the quota.
  EXPECT_EQ(alice->Delete(endless->id()).status().code(), absl::StatusCode::kFailedPrecondition);
  ASSERT_TRUE(alice->Cancel(endless->id()).ok());
  alice->Watch(endless->id(), {}, [](const v1::WatchJobResponse&) {}).IgnoreError();

  // Results: one kept result passes the 1-byte quota; the next job waits.
  const v1::Job done = Run(*alice, SmallJob());
  auto over = alice->Submit(SmallJob());
  EXPECT_EQ(over.status().code(), absl::StatusCode::kResourceExhausted);
  EXPECT_THAT(
      over.status().message(),
      HasSubstr(absl::StrCat("result quota: principal alice keeps ", done.result().size_bytes(),
                             " bytes of results, the quota is 1 bytes")));
  // Quotas are per principal.
  EXPECT_TRUE(bob->Submit(SmallJob()).ok());

  // Assets: 600 bytes fit, 600 more do not; the same bytes again cost nothing.
  const std::string a(600, 'a'), b(600, 'b');
  ASSERT_TRUE(alice->UploadBytes("a.bin", a, Sha256Hex(a), a.size()).ok());
  ASSERT_TRUE(alice->UploadBytes("a.bin", a, Sha256Hex(a), a.size()).ok());
  auto full = alice->UploadBytes("b.bin", b, Sha256Hex(b), b.size());
  EXPECT_EQ(full.status().code(), absl::StatusCode::kResourceExhausted);
  EXPECT_THAT(full.status().message(),
              HasSubstr("asset quota: principal alice stores 600 bytes of assets; this upload of "
                        "600 bytes would pass the quota of 1000 bytes"));
  EXPECT_TRUE(bob->UploadBytes("b.bin", b, Sha256Hex(b), b.size()).ok());
}

TEST_F(SecurityE2E, ResultsExpireUnlessPinned) {
  StartWithTokens({"--retention-seconds", "2"});
  auto alice = As(kAlice);
  const v1::Job kept = Run(*alice, SmallJob());
  ASSERT_TRUE(alice->Pin(kept.id(), true).ok());
  const v1::Job gone = Run(*alice, SmallJob());
  ASSERT_TRUE(std::filesystem::exists(ResultPath(gone.id())));
  const std::string blob = "an asset nobody uses";
  ASSERT_TRUE(alice->UploadBytes("blob.bin", blob, Sha256Hex(blob), blob.size()).ok());
  const std::filesystem::path asset = dir_ / "data" / "assets" / Sha256Hex(blob);
  ASSERT_TRUE(std::filesystem::exists(asset));

  // The sweep runs every few hundred ms; allow it a generous while.
  v1::Job expired;
  for (int i = 0; i < 150 && !expired.has_result_expire_time(); ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    expired = *alice->Get(gone.id());
  }
  ASSERT_TRUE(expired.has_result_expire_time()) << "the result never expired";
  EXPECT_FALSE(std::filesystem::exists(ResultPath(gone.id())));
  const absl::Status fetch = alice->Fetch(gone.id(), dir_ / "late.vdb");
  EXPECT_EQ(fetch.code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_THAT(fetch.message(),
              HasSubstr(absl::StrCat("the result of job ", gone.id(), " expired")));
  for (int i = 0; i < 50 && std::filesystem::exists(asset); ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  EXPECT_FALSE(std::filesystem::exists(asset));

  // The pinned job kept everything.
  auto pinned = alice->Get(kept.id());
  ASSERT_TRUE(pinned.ok());
  EXPECT_TRUE(pinned->pinned());
  EXPECT_FALSE(pinned->has_result_expire_time());
  ASSERT_TRUE(alice->Fetch(kept.id(), dir_ / "kept.vdb").ok());
  EXPECT_EQ(*Sha256File(dir_ / "kept.vdb"), kept.result().sha256());
}

TEST_F(SecurityE2E, DeleteRemovesTheJobAndItsFiles) {
  StartWithTokens();
  auto alice = As(kAlice);
  const v1::Job job = Run(*alice, SmallJob());
  ASSERT_TRUE(std::filesystem::exists(ResultPath(job.id())));
  auto freed = alice->Delete(job.id());
  ASSERT_TRUE(freed.ok()) << freed.status();
  EXPECT_EQ(*freed, job.result().size_bytes());
  EXPECT_FALSE(std::filesystem::exists(ResultPath(job.id())));
  EXPECT_EQ(alice->Get(job.id()).status().code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(alice->List(v1::ListJobsRequest())->jobs_size(), 0);
}

// Runs the nimbus CLI; its exit code, and its stdout in `out`.
int Cli(const std::string& args, std::string* out = nullptr) {
  const std::string cmd = std::string(NIMBUS_BIN_DIR) + "/nimbus " + args + " 2>/dev/null";
  FILE* p = ::popen(cmd.c_str(), "r");
  std::string text;
  char buf[256];
  while (p != nullptr && std::fgets(buf, sizeof buf, p) != nullptr) text += buf;
  const int rc = p == nullptr ? -1 : ::pclose(p);
  if (out != nullptr) *out = text;
  return WEXITSTATUS(rc);
}

TEST_F(SecurityE2E, CliSpeaksTlsSendsTheTokenAndPinsAndDeletes) {
  auto pki = testing::MakeTestPki(dir_ / "pki");
  ASSERT_TRUE(pki.ok()) << pki.status();
  StartWithTokens({"--tls-cert", pki->server_cert.string(), "--tls-key", pki->server_key.string()});
  const std::filesystem::path spec = dir_ / "small.json";
  std::ofstream(spec) << spec::SpecToJson(SmallJob());
  const std::string tls =
      absl::StrCat("--server ", server_.target(), " --tls-ca ", pki->ca_cert.string());
  const std::string alice = absl::StrCat(tls, " --token ", kAlice);

  std::string out;
  EXPECT_EQ(Cli(tls + " jobs"), 2);  // no token: UNAUTHENTICATED
  EXPECT_EQ(
      Cli(absl::StrCat(alice, " render ", spec.string(), " -o ", (dir_ / "out.vdb").string())), 0);
  ConnectOptions o;
  o.tls_ca_file = pki->ca_cert.string();
  o.token = kAlice;
  auto c = NimbusClient::Connect(server_.target(), o);
  ASSERT_TRUE(c.ok());
  auto list = (*c)->List(v1::ListJobsRequest());
  ASSERT_TRUE(list.ok()) << list.status();
  ASSERT_EQ(list->jobs_size(), 1);
  const std::string id = list->jobs(0).id();
  EXPECT_EQ(*Sha256File(dir_ / "out.vdb"), list->jobs(0).result().sha256());

  EXPECT_EQ(Cli(absl::StrCat(alice, " pin ", id), &out), 0);
  EXPECT_EQ(out, id + " pinned\n");
  EXPECT_TRUE((*c)->Get(id)->pinned());
  EXPECT_EQ(Cli(absl::StrCat(alice, " unpin ", id), &out), 0);
  EXPECT_FALSE((*c)->Get(id)->pinned());
  // Bob's token: the job does not exist for him.
  EXPECT_EQ(Cli(absl::StrCat(tls, " --token ", kBob, " delete ", id)), 2);
  EXPECT_EQ(Cli(absl::StrCat(alice, " delete ", id), &out), 0);
  EXPECT_THAT(out, HasSubstr(id + " deleted"));
  EXPECT_FALSE(std::filesystem::exists(ResultPath(id)));
  EXPECT_EQ((*c)->Get(id).status().code(), absl::StatusCode::kNotFound);
}

// The result cache answers a principal only from its own jobs
// (docs/result_cache.md): alice's resubmission is a hit, bob's submission
// of the very same spec runs on its own.
TEST_F(SecurityE2E, TheCacheNeverAnswersOnePrincipalWithAnothersResult) {
  StartWithTokens();
  auto alice = As(kAlice), bob = As(kBob);
  const v1::Job first = Run(*alice, SmallJob());
  auto hit = alice->Submit(SmallJob());
  ASSERT_TRUE(hit.ok()) << hit.status();
  EXPECT_EQ(hit->cached_from(), first.id());
  auto other = bob->Submit(SmallJob());
  ASSERT_TRUE(other.ok()) << other.status();
  EXPECT_EQ(other->owner(), "bob");
  EXPECT_EQ(other->cached_from(), "") << "bob was answered with alice's result";
  auto done = bob->Watch(other->id(), {}, [](const v1::WatchJobResponse&) {});
  ASSERT_TRUE(done.ok()) << done.status();
  EXPECT_EQ(done->state(), v1::JOB_STATE_SUCCEEDED);
  EXPECT_EQ(done->cached_from(), "");
}

}  // namespace
}  // namespace nimbus
