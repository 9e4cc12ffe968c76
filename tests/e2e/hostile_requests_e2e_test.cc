// Hostile requests sent straight to a real nimbusd over gRPC, as a client
// that does not use the nimbus CLI would send them: asset paths naming the
// server's own files, oversized and unknown-field specs, undecodable
// requests, cross-principal probes, bad TLS files, and a job store that
// lost its jobs.
#include <gmock/gmock.h>
#include <grpcpp/generic/generic_stub.h>
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>
#include <sys/inotify.h>
#include <sys/stat.h>
#include <unistd.h>

#include <fstream>
#include <future>
#include <map>
#include <thread>

#include "absl/strings/str_cat.h"
#include "client/nimbus_client.h"
#include "core/base/sha256.h"
#include "nimbus/v1/nimbus_service.grpc.pb.h"
#include "proto/spec_io.h"
#include "tests/support/e2e_clients.h"
#include "tests/support/nimbusd_process.h"
#include "tests/support/test_pki.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

using client::NimbusClient;
using ::testing::HasSubstr;
using ::testing::Not;

constexpr char kAlice[] = "alice-token-0123456789abcdef";
constexpr char kBob[] = "bob-token-0123456789abcdef00";

std::string ReadAll(const std::filesystem::path& p) { return testing::ReadFileBytes(p); }

v1::JobSpec ParseJson(const std::string& json) {
  auto spec = spec::ParseSpec(json, spec::SpecFormat::kJson);
  EXPECT_TRUE(spec.ok()) << spec.status();
  return spec.ok() ? *spec : v1::JobSpec();
}

v1::JobSpec SmallJob() { return testing::SmallTetrahedronJob(); }

// Specs naming `path` as every kind of asset a spec can name, with the
// field the refusal must name.
std::vector<std::pair<std::string, v1::JobSpec>> AssetSpecs(const std::string& path) {
  const std::string asset = absl::StrCat(R"({"path": ")", path, R"(", "label": "x.stl"})");
  const std::string bare = absl::StrCat(R"({"path": ")", path, R"("})");
  return {
      {"set_ifs.maps[0].condensation.mesh.asset.path",
       ParseJson(absl::StrCat(R"({"set_ifs": {"maps": [{"condensation": {"mesh": {"asset": )",
                              asset, R"(}}}], "random": {"iterations": "3"}}})"))},
      {"set_ifs.maps[0].condensation.mesh.asset.path",
       ParseJson(absl::StrCat(R"({"set_ifs": {"maps": [{"condensation": {"mesh": {"asset": )", bare,
                              R"(}}}], "random": {"iterations": "3"}}})"))},
      {"set_ifs.maps[0].condensation.grid.asset.path",
       ParseJson(absl::StrCat(R"({"set_ifs": {"maps": [{"condensation": {"grid": {"asset": )", bare,
                              R"(}}}], "random": {"iterations": "3"}}})"))},
      {"set_ifs.start.union.parts[1].mesh.asset.path",
       ParseJson(absl::StrCat(R"({"set_ifs": {"start": {"union": {"parts": [{"sphere": {}},)",
                              R"({"mesh": {"asset": )", asset, R"(}}]}}}})"))},
      {"fractal_field.shape.source.mesh.asset.path",
       ParseJson(absl::StrCat(R"({"fractal_field": {"shape": {"source": {"mesh": {"asset": )",
                              asset, R"(}}}}})"))},
  };
}

// `bytes` sent as the request of `method`, whatever they are.
grpc::Status CallRaw(grpc::GenericStub& generic, const std::string& method,
                     const std::string& bytes) {
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(30));
  grpc::Slice slice(bytes);
  grpc::ByteBuffer request(&slice, 1), response;
  std::promise<grpc::Status> result;
  generic.UnaryCall(&ctx, method, grpc::StubOptions(), &request, &response,
                    [&](grpc::Status st) { result.set_value(std::move(st)); });
  return result.get_future().get();
}

class HostileRequestsE2E : public ::testing::Test {
 protected:
  std::filesystem::path TokensFile() {
    const std::filesystem::path path = dir_ / "tokens";
    std::ofstream(path) << kAlice << " alice\n" << kBob << " bob\n";
    ::chmod(path.c_str(), 0600);
    return path;
  }

  void Start(std::vector<std::string> more = {}) {
    std::vector<std::string> args = {"--workers",   "1",    "--threads-per-job",   "2",
                                     "--log-level", "info", "--min-free-disk-mib", "0"};
    args.insert(args.end(), more.begin(), more.end());
    server_.set_args(args);
    server_.set_log_file(dir_ / "nimbusd.log");
    const absl::Status s = server_.Start();
    ASSERT_TRUE(s.ok()) << s << "\n" << ReadAll(dir_ / "nimbusd.log");
  }

  std::unique_ptr<v1::NimbusService::Stub> Stub() {
    return v1::NimbusService::NewStub(
        grpc::CreateChannel(server_.target(), grpc::InsecureChannelCredentials()));
  }

  // SubmitJob sent as is, with `token` as the bearer token when not empty.
  grpc::Status Submit(const v1::JobSpec& spec, const std::string& token = "",
                      const std::string& request_id = "", v1::SubmitJobResponse* out = nullptr) {
    grpc::ClientContext ctx;
    if (!token.empty()) ctx.AddMetadata("authorization", absl::StrCat("Bearer ", token));
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(60));
    v1::SubmitJobRequest req;
    *req.mutable_spec() = spec;
    req.set_request_id(request_id);
    v1::SubmitJobResponse resp;
    return Stub()->SubmitJob(&ctx, req, out != nullptr ? out : &resp);
  }

  std::unique_ptr<NimbusClient> As(const std::string& token) {
    return testing::ConnectAs(server_.target(), token);
  }

  // The answers to specs naming each of `paths` as every kind of asset;
  // every path must get the same words for the same field.
  void ExpectPathsRefusedAlike(const std::vector<std::string>& paths, const std::string& token) {
    std::map<std::string, std::string> first_answer;  // by field
    for (const std::string& path : paths) {
      for (const auto& [field, spec] : AssetSpecs(path)) {
        const grpc::Status st = Submit(spec, token);
        EXPECT_EQ(st.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << path << " " << field;
        const std::string& msg = st.error_message();
        EXPECT_THAT(msg, HasSubstr(field + ": this server never opens files named in a spec"));
        EXPECT_THAT(msg, Not(HasSubstr(path)));
        auto [it, fresh] = first_answer.emplace(field, msg);
        if (!fresh) EXPECT_EQ(msg, it->second) << "answer depends on what is at " << path;
      }
    }
  }

  testing::TempDir dir_;
  testing::NimbusdProcess server_{dir_ / "data"};
};

// A network client names files of the server's host: an STL-like file the
// server's user can read, the server's own tokens file, a folder, a missing
// path and a file no one may read. The answer is the same for each, names
// only the field, and the server never opens the file (inotify sees no
// open or read of it).
TEST_F(HostileRequestsE2E, AssetPathsAreRefusedAlikeAndNeverOpened) {
  const std::filesystem::path secret = dir_ / "secret.stl";
  std::ofstream(secret, std::ios::binary)
      << std::string(80, 's') << std::string("\x03\0\0\0", 4) << std::string(150, 't');
  const std::filesystem::path unreadable = dir_ / "unreadable.obj";
  std::ofstream(unreadable) << "v 0 0 0\n";
  ::chmod(unreadable.c_str(), 0);
  const std::vector<std::string> paths = {secret.string(),      (dir_ / "tokens").string(),
                                          dir_.path().string(), (dir_ / "missing.ply").string(),
                                          unreadable.string(),  "relative/cow.obj"};
  const int watch = ::inotify_init1(IN_NONBLOCK);
  ASSERT_GE(watch, 0);
  ASSERT_GE(::inotify_add_watch(watch, secret.c_str(), IN_OPEN | IN_ACCESS), 0);

  Start({"--auth-tokens", TokensFile().string()});
  ASSERT_GE(::inotify_add_watch(watch, (dir_ / "tokens").c_str(), IN_OPEN | IN_ACCESS), 0);
  ExpectPathsRefusedAlike(paths, kAlice);  // a principal without the admin role
  server_.Stop();

  Start();  // no tokens: the anonymous admin of a loopback server
  ExpectPathsRefusedAlike(paths, "");
  char events[4096];
  EXPECT_EQ(::read(watch, events, sizeof(events)), -1) << "nimbusd opened a file a spec named";
  ::close(watch);
  // The job list holds none of them.
  v1::ListJobsRequest list;
  EXPECT_EQ(As("")->List(list)->jobs_size(), 0);
}

// Specs are bounded before they are copied or stored: unknown fields at
// any depth, a palette of a million stops, and a spec over 4 MiB are
// refused by field; nimbusd's memory stays far below what storing them
// took.
TEST_F(HostileRequestsE2E, OversizedAndUnknownFieldsAreRefusedByField) {
  Start();
  v1::JobSpec unknown_top = SmallJob();
  unknown_top.GetReflection()
      ->MutableUnknownFields(&unknown_top)
      ->AddLengthDelimited(9999, std::string(1 << 20, 'u'));
  grpc::Status st = Submit(unknown_top);
  EXPECT_EQ(st.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_THAT(st.error_message(), HasSubstr("spec: has a field this server does not know (field "
                                            "number 9999)"));

  v1::JobSpec unknown_deep = SmallJob();
  auto* map = unknown_deep.mutable_chaos_game()->mutable_ifs()->mutable_maps(2);
  map->GetReflection()->MutableUnknownFields(map)->AddVarint(777, 1);
  st = Submit(unknown_deep);
  EXPECT_EQ(st.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_THAT(st.error_message(),
              HasSubstr("chaos_game.ifs.maps[2]: has a field this server does not know"));

  v1::JobSpec stops = SmallJob();
  auto* palette = stops.mutable_chaos_game()->mutable_color()->mutable_palette();
  for (int i = 0; i < 1'000'000; ++i) palette->add_stops()->set_position(i * 1e-6);
  for (int i = 0; i < 6; ++i) {
    st = Submit(stops);
    EXPECT_EQ(st.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
    EXPECT_THAT(st.error_message(),
                HasSubstr("spec: must be at most 4194304 bytes serialised, got 1"));
  }
  stops.mutable_chaos_game()->mutable_color()->mutable_palette()->mutable_stops()->DeleteSubrange(
      5000, 1'000'000 - 5000);
  st = Submit(stops);
  EXPECT_EQ(st.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_THAT(
      st.error_message(),
      HasSubstr("chaos_game.color.palette.stops: must have at most 4096 entries, got 5000"));

  // Six 22 MB submissions left nimbusd at over a gigabyte when each was
  // parsed, copied and stored.
  const std::string status = ReadAll(absl::StrCat("/proc/", server_.pid(), "/status"));
  const size_t at = status.find("VmRSS:");
  ASSERT_NE(at, std::string::npos);
  const long rss_kib = std::strtol(status.c_str() + at + 6, nullptr, 10);
  EXPECT_LT(rss_kib, 400 * 1024) << "nimbusd holds " << rss_kib << " KiB";
  // Nothing was stored.
  EXPECT_EQ(As("")->List(v1::ListJobsRequest())->jobs_size(), 0);
}

// Bytes that are no request message: gRPC cannot parse them, and the
// caller is told so as INVALID_ARGUMENT, for unary and streaming calls.
TEST_F(HostileRequestsE2E, UndecodableRequestsAreInvalidArgument) {
  Start();
  auto channel = grpc::CreateChannel(server_.target(), grpc::InsecureChannelCredentials());
  grpc::GenericStub generic(channel);
  // Nested SetSource unions 150 deep: protobuf refuses past 100 levels.
  v1::JobSpec deep;
  v1::SetSource* s = deep.mutable_set_ifs()->mutable_start();
  for (int i = 0; i < 150; ++i) s = s->mutable_union_()->add_parts();
  v1::SubmitJobRequest deep_req;
  *deep_req.mutable_spec() = deep;
  const std::string invalid_utf8 = std::string("\x0a\x03\xff\xfe\xfd", 5);  // job_id
  const std::pair<std::string, std::string> cases[] = {
      {"/nimbus.v1.NimbusService/SubmitJob", "\xff\xff\xff\xff garbage"},
      {"/nimbus.v1.NimbusService/GetJob", invalid_utf8},
      {"/nimbus.v1.NimbusService/SubmitJob", deep_req.SerializeAsString()},
      {"/nimbus.v1.NimbusService/WatchJob", invalid_utf8},
      {"/nimbus.v1.NimbusService/CancelJob", "\x0a\x7f short"},
  };
  for (const auto& [method, bytes] : cases) {
    const grpc::Status st = CallRaw(generic, method, bytes);
    EXPECT_EQ(st.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << method;
    EXPECT_THAT(st.error_message(), HasSubstr("request could not be parsed")) << method;
  }
  // A method the service does not have is still UNIMPLEMENTED.
  EXPECT_EQ(CallRaw(generic, "/nimbus.v1.NimbusService/NoSuchCall", "").error_code(),
            grpc::StatusCode::UNIMPLEMENTED);
}

// What one principal stored or keyed tells another nothing: bytes only
// Alice uploaded answer Bob as a first upload, and Bob's use of Alice's
// request_id makes a job of his own.
TEST_F(HostileRequestsE2E, AnotherPrincipalsUploadsAndKeysAreInvisible) {
  Start({"--auth-tokens", TokensFile().string()});
  const std::string bytes =
      "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n";
  const std::string sha = Sha256Hex(bytes);
  auto alice = As(kAlice);
  auto bob = As(kBob);
  auto first = alice->UploadBytes("tet.obj", bytes, sha, bytes.size());
  ASSERT_TRUE(first.ok()) << first.status();
  EXPECT_FALSE(first->already_present());
  auto again = alice->UploadBytes("tet.obj", bytes, sha, bytes.size());
  ASSERT_TRUE(again.ok());
  EXPECT_TRUE(again->already_present());
  auto bobs = bob->UploadBytes("mine.obj", bytes, sha, bytes.size());
  ASSERT_TRUE(bobs.ok()) << bobs.status();
  EXPECT_FALSE(bobs->already_present()) << "Bob learnt that someone had uploaded these bytes";
  auto bobs_again = bob->UploadBytes("mine.obj", bytes, sha, bytes.size());
  ASSERT_TRUE(bobs_again.ok());
  EXPECT_TRUE(bobs_again->already_present());

  v1::SubmitJobResponse a, b, b2;
  ASSERT_TRUE(Submit(SmallJob(), kAlice, "render-42", &a).ok());
  v1::JobSpec other = SmallJob();
  other.set_name("bobs_own");
  const grpc::Status st = Submit(other, kBob, "render-42", &b);
  ASSERT_TRUE(st.ok()) << st.error_message();
  EXPECT_NE(b.job().id(), a.job().id());
  EXPECT_EQ(b.job().owner(), "bob");
  // Bob's retry finds his own job.
  ASSERT_TRUE(Submit(other, kBob, "render-42", &b2).ok());
  EXPECT_EQ(b2.job().id(), b.job().id());
}

// A certificate or key that is not what it should be stops nimbusd at
// start with the file named and why, not a failure to listen.
TEST_F(HostileRequestsE2E, BadTlsFilesAreNamedAtStart) {
  auto pki = testing::MakeTestPki(dir_ / "pki");
  ASSERT_TRUE(pki.ok()) << pki.status();
  const std::filesystem::path garbage = dir_ / "garbage.pem";
  std::ofstream(garbage) << "this is not a certificate\n";
  const std::filesystem::path broken = dir_ / "broken.pem";
  std::ofstream(broken) << "-----BEGIN CERTIFICATE-----\nAAAA!!!!\n-----END CERTIFICATE-----\n";
  struct Case {
    std::string cert, key, want;
  } cases[] = {
      {garbage.string(), pki->server_key.string(),
       "--tls-cert " + garbage.string() + ": no PEM certificate in it"},
      {broken.string(), pki->server_key.string(),
       "--tls-cert " + broken.string() + ": certificate 1 is not valid"},
      {pki->server_cert.string(), garbage.string(),
       "--tls-key " + garbage.string() + ": not a PEM private key"},
      {pki->server_cert.string(), pki->client_key.string(),
       "--tls-key " + pki->client_key.string() + ": is not the key of the certificate in"},
  };
  for (const Case& c : cases) {
    server_.set_log_file(dir_ / "nimbusd.log");
    server_.set_args({"--tls-cert", c.cert, "--tls-key", c.key});
    EXPECT_FALSE(server_.Start().ok());
    const std::string log = ReadAll(dir_ / "nimbusd.log");
    EXPECT_THAT(log, HasSubstr(c.want));
    EXPECT_THAT(log, Not(HasSubstr("cannot listen")));
  }
}

// A clean stop leaves every job in jobs.db itself: garbage where the WAL
// was loses nothing. A store that did lose its jobs is reported at start,
// naming the result files it does not know.
TEST_F(HostileRequestsE2E, CleanStopCheckpointsAndLostJobsAreReported) {
  Start();
  auto c = As("");
  auto job = c->Submit(SmallJob());
  ASSERT_TRUE(job.ok()) << job.status();
  auto done = c->Watch(job->id(), {}, [](const v1::WatchJobResponse&) {});
  ASSERT_TRUE(done.ok()) << done.status();
  ASSERT_EQ(done->state(), v1::JOB_STATE_SUCCEEDED);
  c.reset();
  EXPECT_EQ(server_.Stop(), 0);
  const std::filesystem::path db = dir_ / "data" / "jobs.db";
  const std::filesystem::path wal = db.string() + "-wal";
  EXPECT_FALSE(std::filesystem::exists(wal));
  std::ofstream(wal, std::ios::binary) << std::string(8192, '\x77');
  Start();
  EXPECT_TRUE(As("")->Get(job->id()).ok());
  EXPECT_THAT(ReadAll(dir_ / "nimbusd.log"), Not(HasSubstr("event=unknown_results")));
  EXPECT_EQ(server_.Stop(), 0);

  // The job database is lost; its result file is not.
  for (const char* suffix : {"", "-wal", "-shm"}) std::filesystem::remove(db.string() + suffix);
  Start();
  const std::string log = ReadAll(dir_ / "nimbusd.log");
  EXPECT_THAT(log, HasSubstr("event=unknown_results count=1 checked=1"));
  EXPECT_THAT(log, HasSubstr(job->id()));
}

}  // namespace
}  // namespace nimbus
