// The HTTP port against a real nimbusd on loopback, through httplib's
// client: every /api/v1 call, its errors, ownership, Range resumption,
// previews, the event stream, hostile inputs, a flood of event streams, and
// /metrics checked by Prometheus' own promtool.
#include <google/protobuf/util/json_util.h>
#include <gtest/gtest.h>
#include <httplib.h>
#include <sys/stat.h>

#include <atomic>
#include <fstream>
#include <sstream>
#include <thread>

#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "core/io/image_io.h"
#include "proto/spec_io.h"
#include "tests/support/e2e_clients.h"
#include "tests/support/nimbusd_process.h"
#include "tests/support/postgres_server.h"
#include "tests/support/test_pki.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

constexpr char kAlice[] = "alice-token-0123456789abcdef";
constexpr char kBob[] = "bob-token-0123456789abcdef00";

std::string ReadAll(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

v1::JobSpec EndlessJob() {
  v1::JobSpec spec = testing::SmallTetrahedronJob();
  spec.mutable_chaos_game()->set_iterations(uint64_t{1} << 38);
  return spec;
}

std::string SubmitBody(const v1::JobSpec& spec) {
  v1::SubmitJobRequest req;
  *req.mutable_spec() = spec;
  std::string json;
  EXPECT_TRUE(google::protobuf::util::MessageToJsonString(req, &json).ok());
  return json;
}

template <typename M>
M Parse(const std::string& json) {
  M m;
  google::protobuf::util::JsonParseOptions o;
  EXPECT_TRUE(google::protobuf::util::JsonStringToMessage(json, &m, o).ok()) << json;
  return m;
}

// httplib's client whose answers are values: a call that got no answer
// reads as status -1 with the error's name as body.
struct Http {
  httplib::Client c;
  static httplib::Response Of(httplib::Result r) {
    if (r) return *r;
    httplib::Response none;
    none.status = -1;
    none.body = httplib::to_string(r.error());
    return none;
  }
  httplib::Response Get(const std::string& path, const httplib::Headers& h = {}) {
    return Of(c.Get(path, h));
  }
  httplib::Response Post(const std::string& path, const std::string& body, const char* type) {
    return Of(c.Post(path, body, type));
  }
  httplib::Response Delete(const std::string& path, const std::string& body, const char* type) {
    return Of(c.Delete(path, body, type));
  }
};

class HttpApi : public ::testing::Test {
 protected:
  void SetUp() override {
    const auto tokens = dir_ / "tokens";
    std::ofstream(tokens) << kAlice << " alice\n" << kBob << " bob\n";
    ::chmod(tokens.c_str(), 0600);
    server_.set_args({"--workers", "2", "--threads-per-job", "1", "--log-level", "warn",
                      "--min-free-disk-mib", "0", "--auth-tokens", tokens.string(), "--http",
                      "127.0.0.1:0", "--http-port-file", (dir_ / "http_port").string()});
    ASSERT_TRUE(server_.Start().ok());
    http_port_ = std::stoi(ReadAll(dir_ / "http_port"));
  }

  httplib::Client Raw(const std::string& token = kAlice) {
    httplib::Client c("127.0.0.1", http_port_);
    if (!token.empty()) c.set_bearer_token_auth(token);
    c.set_read_timeout(60, 0);
    return c;
  }
  Http Client(const std::string& token = kAlice) { return Http{Raw(token)}; }

  v1::Job Submit(const v1::JobSpec& spec, const std::string& token = kAlice) {
    auto r = Client(token).Post("/api/v1/jobs", SubmitBody(spec), "application/json");
    EXPECT_EQ(r.status, 200) << r.body;
    return Parse<v1::SubmitJobResponse>(r.body).job();
  }

  v1::Job Get(const std::string& id) {
    auto r = Client().Get(absl::StrCat("/api/v1/jobs/", id));
    EXPECT_TRUE(r.status == 200);
    return Parse<v1::GetJobResponse>(r.body).job();
  }

  // Polls until the job leaves QUEUED/RUNNING (bounded by the job's size).
  v1::Job AwaitEnd(const std::string& id) {
    for (int i = 0; i < 6000; ++i) {
      v1::Job j = Get(id);
      if (j.state() >= v1::JOB_STATE_SUCCEEDED) return j;
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    ADD_FAILURE() << "job " << id << " never ended";
    return {};
  }

  v1::Job AwaitRunning(const std::string& id) {
    for (int i = 0; i < 6000; ++i) {
      v1::Job j = Get(id);
      if (j.state() == v1::JOB_STATE_RUNNING && j.progress().done() > 0) return j;
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    ADD_FAILURE() << "job " << id << " never ran";
    return {};
  }

  testing::TempDir dir_;
  testing::NimbusdProcess server_{dir_ / "data"};
  int http_port_ = 0;
};

TEST_F(HttpApi, SubmitGetListDownloadWithRangeMatchesGrpcFetch) {
  const v1::Job submitted = Submit(testing::SmallTetrahedronJob());
  ASSERT_FALSE(submitted.id().empty());
  const v1::Job done = AwaitEnd(submitted.id());
  ASSERT_EQ(done.state(), v1::JOB_STATE_SUCCEEDED) << done.error();
  EXPECT_EQ(done.owner(), "alice");

  auto list = Client().Get("/api/v1/jobs?state=SUCCEEDED&page_size=10");
  ASSERT_TRUE(list.status == 200);
  auto jobs = Parse<v1::ListJobsResponse>(list.body);
  ASSERT_EQ(jobs.jobs_size(), 1);
  EXPECT_EQ(jobs.jobs(0).id(), submitted.id());
  auto none = Client().Get("/api/v1/jobs?state=QUEUED");
  EXPECT_EQ(Parse<v1::ListJobsResponse>(none.body).jobs_size(), 0);

  // The reference: the same result fetched over gRPC by the CLI's client.
  auto grpc = testing::ConnectAs(server_.target(), kAlice);
  ASSERT_NE(grpc, nullptr);
  ASSERT_TRUE(grpc->Fetch(submitted.id(), dir_ / "grpc.vdb").ok());
  const std::string expected = ReadAll(dir_ / "grpc.vdb");
  ASSERT_GT(expected.size(), 200u);

  const std::string path = absl::StrCat("/api/v1/jobs/", submitted.id(), "/result");
  auto whole = Client().Get(path);
  ASSERT_TRUE(whole.status == 200);
  EXPECT_EQ(whole.body, expected);
  EXPECT_EQ(whole.get_header_value("X-Nimbus-Sha256"), done.result().sha256());
  // A resumed download (curl -C - sends "Range: bytes=N-").
  auto tail = Client().Get(path, {{"Range", "bytes=100-"}});
  EXPECT_EQ(tail.status, 206);
  EXPECT_EQ(tail.body, expected.substr(100));
  EXPECT_EQ(tail.get_header_value("Content-Range"),
            absl::StrCat("bytes 100-", expected.size() - 1, "/", expected.size()));
  auto middle = Client().Get(path, {{"Range", "bytes=10-19"}});
  EXPECT_EQ(middle.body, expected.substr(10, 10));
  auto beyond = Client().Get(path, {{"Range", absl::StrCat("bytes=", expected.size() + 5, "-")}});
  EXPECT_EQ(beyond.status, 416);
  EXPECT_EQ(beyond.get_header_value("Content-Range"), absl::StrCat("bytes */", expected.size()));
}

TEST_F(HttpApi, FramesDownloadByNameWithRange) {
  // A set-IFS book: one file per page (8 at depth 3).
  auto spec = spec::LoadSpecFile(testing::SourcePath("examples/morph_book.json"));
  ASSERT_TRUE(spec.ok()) << spec.status();
  spec->mutable_grid()->set_resolution(0, 32);
  spec->mutable_set_ifs()->mutable_book()->set_depth(3);
  auto grpc = testing::ConnectAs(server_.target(), kAlice);
  ASSERT_NE(grpc, nullptr);
  ASSERT_TRUE(grpc->UploadSpecAssets(*spec, testing::SourcePath("examples")).ok());
  const v1::Job done = AwaitEnd(Submit(*spec).id());
  ASSERT_EQ(done.state(), v1::JOB_STATE_SUCCEEDED) << done.error();
  ASSERT_EQ(done.result().files_size(), 8);
  const std::string name = done.result().files(3).file_name();
  ASSERT_TRUE(grpc->Fetch(done.id(), dir_ / "page.vdb", name).ok());
  const std::string expected = ReadAll(dir_ / "page.vdb");
  const std::string path = absl::StrCat("/api/v1/jobs/", done.id(), "/files/", name);
  auto whole = Client().Get(path);
  ASSERT_EQ(whole.status, 200) << whole.body;
  EXPECT_EQ(whole.body, expected);
  EXPECT_EQ(whole.get_header_value("X-Nimbus-Sha256"), done.result().files(3).sha256());
  auto tail = Client().Get(path, {{"Range", "bytes=64-"}});
  EXPECT_EQ(tail.status, 206);
  EXPECT_EQ(tail.body, expected.substr(64));
  EXPECT_EQ(Client().Get(absl::StrCat(path, ".missing")).status, 404);
}

TEST_F(HttpApi, AnotherOwnersJobIsNotFoundAndTokensAreRequired) {
  const v1::Job job = Submit(EndlessJob());
  const std::string path = absl::StrCat("/api/v1/jobs/", job.id());
  EXPECT_EQ(Client(kBob).Get(path).status, 404);
  EXPECT_EQ(Client(kBob).Post(path + "/cancel", "{}", "application/json").status, 404);
  EXPECT_EQ(Client(kBob).Delete(path, "{}", "application/json").status, 404);
  EXPECT_EQ(Client(kBob).Get(path + "/stream").status, 404);
  EXPECT_EQ(Client(kBob).Get(path + "/preview.png").status, 404);
  auto bob_list = Client(kBob).Get("/api/v1/jobs");
  EXPECT_EQ(Parse<v1::ListJobsResponse>(bob_list.body).jobs_size(), 0);
  auto anonymous = Client("").Get(path);
  EXPECT_EQ(anonymous.status, 401);
  EXPECT_NE(anonymous.body.find("UNAUTHENTICATED"), std::string::npos);
  EXPECT_EQ(Client("wrong-token-0123456789abcdef").Get("/api/v1/jobs").status, 401);
  // Operators' endpoints need no token.
  EXPECT_EQ(Client("").Get("/healthz").status, 200);
  EXPECT_EQ(Client("").Get("/readyz").status, 200);

  auto cancelled = Client().Post(path + "/cancel", "{}", "application/json");
  ASSERT_EQ(cancelled.status, 200) << cancelled.body;
  EXPECT_EQ(AwaitEnd(job.id()).state(), v1::JOB_STATE_CANCELLED);
}

TEST_F(HttpApi, PinAndDelete) {
  const v1::Job job = Submit(testing::SmallTetrahedronJob());
  const v1::Job done = AwaitEnd(job.id());
  ASSERT_GT(done.result().size_bytes(), 0u);
  const std::string path = absl::StrCat("/api/v1/jobs/", job.id());
  auto pinned = Client().Post(path + "/pin", "", "application/json");
  ASSERT_EQ(pinned.status, 200);
  EXPECT_TRUE(Parse<v1::PinJobResponse>(pinned.body).job().pinned());
  auto unpinned = Client().Post(path + "/pin", R"({"pinned":false})", "application/json");
  EXPECT_FALSE(Parse<v1::PinJobResponse>(unpinned.body).job().pinned());
  auto deleted = Client().Delete(path, "{}", "application/json");
  ASSERT_EQ(deleted.status, 200) << deleted.body;
  EXPECT_EQ(Parse<v1::DeleteJobResponse>(deleted.body).freed_bytes(), done.result().size_bytes());
  EXPECT_EQ(Client().Get(path).status, 404);
}

TEST_F(HttpApi, HostileInputsAreRefusedWithClearErrors) {
  auto c = Client();
  auto malformed = c.Post("/api/v1/jobs", "{\"spec\": {", "application/json");
  EXPECT_EQ(malformed.status, 400);
  EXPECT_NE(malformed.body.find("body: not a nimbus.v1.SubmitJobRequest"), std::string::npos);
  auto unknown = c.Post("/api/v1/jobs", R"({"spek": {}})", "application/json");
  EXPECT_EQ(unknown.status, 400);
  v1::JobSpec bad = testing::SmallTetrahedronJob();
  bad.mutable_grid()->set_resolution(0, 0);
  auto invalid = c.Post("/api/v1/jobs", SubmitBody(bad), "application/json");
  EXPECT_EQ(invalid.status, 400);
  EXPECT_NE(invalid.body.find("grid.resolution"), std::string::npos) << invalid.body;
  auto huge = c.Post("/api/v1/jobs", std::string(9 << 20, '{'), "application/json");
  EXPECT_EQ(huge.status, 413);
  auto form = c.Post("/api/v1/jobs", SubmitBody(testing::SmallTetrahedronJob()), "text/plain");
  EXPECT_EQ(form.status, 415);
  EXPECT_EQ(c.Get("/api/v1/jobs?state=SLEEPING").status, 400);
  EXPECT_EQ(c.Get("/api/v1/jobs?page_size=-3").status, 400);
  EXPECT_EQ(c.Get("/api/v1/jobs/no-such-job").status, 404);
  EXPECT_EQ(c.Get("/api/v1/jobs/%00%ff").status / 100, 4);
  // Traversal in a file name reaches neither the data folder nor /etc.
  const v1::Job job = Submit(testing::SmallTetrahedronJob());
  AwaitEnd(job.id());
  for (const char* name : {"..%2F..%2Fjobs.db", "..%2F..%2F..%2F..%2Fetc%2Fpasswd", "%2e%2e"}) {
    auto r = c.Get(absl::StrCat("/api/v1/jobs/", job.id(), "/files/", name));
    EXPECT_EQ(r.status, 404) << name;
    EXPECT_EQ(r.body.find("SQLite format"), std::string::npos);
    EXPECT_EQ(r.body.find("root:"), std::string::npos);
  }
  EXPECT_EQ(c.Get("/../../etc/passwd").status, 404);
  EXPECT_EQ(c.Get(absl::StrCat("/api/v1/jobs/", job.id(), "/preview.png?resolution=9999")).status,
            400);
}

// Reads a job's event stream until `enough` says so; the events as
// (name, data) pairs.
std::vector<std::pair<std::string, std::string>> ReadEvents(
    httplib::Client& c, const std::string& path,
    const std::function<bool(const std::vector<std::pair<std::string, std::string>>&)>& enough) {
  std::vector<std::pair<std::string, std::string>> events;
  std::string buffered;
  auto r = c.Get(path, [&](const char* data, size_t n) {
    buffered.append(data, n);
    size_t cut;
    while ((cut = buffered.find("\n\n")) != std::string::npos) {
      std::string name, body;
      for (absl::string_view line : absl::StrSplit(buffered.substr(0, cut), '\n')) {
        if (absl::ConsumePrefix(&line, "event: ")) name = std::string(line);
        if (absl::ConsumePrefix(&line, "data: ")) body = std::string(line);
      }
      events.emplace_back(name, body);
      buffered.erase(0, cut + 2);
    }
    return !enough(events);
  });
  return events;
}

TEST_F(HttpApi, EventStreamCarriesStateProgressAndNewPreviews) {
  const v1::Job job = Submit(EndlessJob());
  AwaitRunning(job.id());
  auto c = Raw();
  Http h{Raw()};
  const std::string base = absl::StrCat("/api/v1/jobs/", job.id());
  auto events = ReadEvents(c, base + "/stream?preview_resolution=16&preview_interval=0.05",
                           [](const auto& ev) {
                             int previews = 0;
                             for (const auto& e : ev) previews += e.first == "preview";
                             return previews >= 2;
                           });
  std::vector<uint64_t> sequences;
  for (const auto& [name, data] : events) {
    if (name == "job") EXPECT_EQ(Parse<v1::Job>(data).id(), job.id());
    if (name == "preview") sequences.push_back(Parse<v1::Preview>(data).sequence());
  }
  ASSERT_GE(sequences.size(), 2u);
  EXPECT_LT(sequences[0], sequences[1]);

  // The newest preview as a density array and as a PNG of the same shape.
  auto density = h.Get(base + "/preview.density?resolution=16");
  ASSERT_EQ(density.status, 200) << density.body;
  std::vector<int> shape;
  for (absl::string_view s : absl::StrSplit(density.get_header_value("X-Nimbus-Shape"), ','))
    shape.push_back(std::stoi(std::string(s)));
  ASSERT_EQ(shape.size(), 3u);
  EXPECT_EQ(shape[0], 16);
  ASSERT_EQ(density.body.size(), size_t(4) * shape[0] * shape[1] * shape[2]);
  double total = 0;
  for (size_t i = 0; i < density.body.size(); i += 4) {
    float v;
    std::memcpy(&v, density.body.data() + i, 4);
    total += v;
  }
  EXPECT_GT(total, 0);
  auto png = h.Get(base + "/preview.png?resolution=16");
  ASSERT_EQ(png.status, 200);
  std::ofstream(dir_ / "p.png", std::ios::binary) << png.body;
  auto pixels = ReadPngPixels(dir_ / "p.png");
  ASSERT_TRUE(pixels.ok()) << pixels.status();
  EXPECT_EQ(pixels->width, shape[0]);
  EXPECT_EQ(pixels->height, shape[1]);

  // Cancelling ends the stream with the job CANCELLED.
  std::thread cancel([&] {
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
    Client().Post(base + "/cancel", "{}", "application/json");
  });
  auto tail = ReadEvents(c, base + "/stream", [](const auto&) { return false; });
  cancel.join();
  ASSERT_GE(tail.size(), 2u);
  EXPECT_EQ(tail.back().first, "end");
  EXPECT_EQ(Parse<v1::Job>(tail[tail.size() - 2].second).state(), v1::JOB_STATE_CANCELLED);
}

// With events=1 the stream carries the job's event log, once each and in
// order, as GetJobEvents reads it; events_after_seq resumes after a seq.
TEST_F(HttpApi, EventStreamCarriesTheJobsEventLog) {
  const v1::Job job = Submit(testing::SmallTetrahedronJob());
  auto c = Raw();
  const std::string base = absl::StrCat("/api/v1/jobs/", job.id());
  const auto log_of = [](const std::vector<std::pair<std::string, std::string>>& sse) {
    std::vector<v1::JobEvent> out;
    for (const auto& [name, data] : sse)
      if (name == "event") out.push_back(Parse<v1::JobEvent>(data));
    return out;
  };
  const auto streamed = log_of(ReadEvents(c, base + "/stream?events=1", [](const auto&) {
    return false;  // to the end
  }));
  ASSERT_GE(streamed.size(), 3u);
  EXPECT_EQ(streamed.front().kind(), "submitted");
  EXPECT_EQ(streamed[1].kind(), "claimed");
  EXPECT_EQ(streamed.back().kind(), "succeeded");
  for (size_t i = 0; i < streamed.size(); ++i) EXPECT_EQ(streamed[i].seq(), int64_t(i) + 1);
  auto read = Parse<v1::GetJobEventsResponse>(Client().Get(base + "/events?page_size=500").body);
  ASSERT_EQ(read.events_size(), int(streamed.size()));
  for (size_t i = 0; i < streamed.size(); ++i)
    EXPECT_EQ(read.events(int(i)).kind(), streamed[i].kind());

  const auto resumed = log_of(ReadEvents(c, base + "/stream?events=true&events_after_seq=2",
                                         [](const auto&) { return false; }));
  ASSERT_EQ(resumed.size(), streamed.size() - 2);
  EXPECT_EQ(resumed.front().seq(), 3);
  EXPECT_TRUE(log_of(ReadEvents(c, base + "/stream", [](const auto&) { return false; })).empty());
  auto bad = Client().Get(base + "/stream?events=maybe");
  EXPECT_EQ(bad.status, 400);
  EXPECT_NE(bad.body.find("events: 1, 0, true or false"), std::string::npos) << bad.body;
  bad = Client().Get(base + "/stream?events=1&events_after_seq=-1");
  EXPECT_EQ(bad.status, 400);
  EXPECT_NE(bad.body.find("events_after_seq"), std::string::npos) << bad.body;
}

TEST_F(HttpApi, AFloodOfEventStreamsIsBoundedAndGrpcStaysResponsive) {
  const v1::Job job = Submit(EndlessJob());
  AwaitRunning(job.id());
  const std::string path = absl::StrCat("/api/v1/jobs/", job.id(), "/stream");
  constexpr int kStreams = 100;  // beyond the server's 64
  std::atomic<int> accepted{0}, refused{0};
  std::atomic<bool> release{false};
  std::vector<std::thread> threads;
  for (int i = 0; i < kStreams; ++i)
    threads.emplace_back([&] {
      auto c = Raw();
      c.Get(
          path,
          [&](const httplib::Response& head) {
            (head.status == 200 ? accepted : refused) += 1;
            return head.status == 200;
          },
          [&](const char*, size_t) { return !release.load(); });
    });
  // Every stream is answered (accepted or refused) even when too many ask.
  for (int i = 0; i < 3000 && accepted + refused < kStreams; ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  EXPECT_EQ(accepted.load(), 64);
  EXPECT_EQ(refused.load(), kStreams - 64);
  // With every stream slot taken, gRPC and ordinary HTTP calls still answer.
  auto grpc = testing::ConnectAs(server_.target(), kAlice);
  ASSERT_NE(grpc, nullptr);
  auto got = grpc->Get(job.id());
  ASSERT_TRUE(got.ok()) << got.status();
  EXPECT_EQ(Client().Get("/api/v1/jobs").status, 200);
  release = true;
  ASSERT_TRUE(grpc->Cancel(job.id()).ok());
  for (auto& t : threads) t.join();
}

// Readers that go away while their job sends nothing (a queued job) give
// their stream slots back: the server's keep-alive comments find them.
TEST_F(HttpApi, AbandonedStreamsOfAQuietJobFreeTheirSlots) {
  std::vector<std::string> ids;
  for (int i = 0; i < 3; ++i) ids.push_back(Submit(EndlessJob()).id());  // 2 workers: 1 waits
  AwaitRunning(ids[0]);
  AwaitRunning(ids[1]);
  ASSERT_EQ(Get(ids[2]).state(), v1::JOB_STATE_QUEUED);
  const std::string path = absl::StrCat("/api/v1/jobs/", ids[2], "/stream");
  auto open_one = [&] {  // true when accepted; the reader leaves after the first event
    int status = 0;
    Raw().Get(
        path,
        [&](const httplib::Response& head) {
          status = head.status;
          return status == 200;
        },
        [](const char*, size_t) { return false; });
    return status == 200;
  };
  std::vector<std::thread> readers;
  std::atomic<int> accepted{0};
  for (int i = 0; i < 64; ++i) readers.emplace_back([&] { accepted += open_one(); });
  for (auto& t : readers) t.join();
  ASSERT_EQ(accepted.load(), 64);
  bool again = false;
  for (int i = 0; i < 120 && !again; ++i) {
    again = open_one();
    if (!again) std::this_thread::sleep_for(std::chrono::milliseconds(500));
  }
  EXPECT_TRUE(again) << "the abandoned streams never gave their slots back";
  for (const std::string& id : ids)
    Client().Post(absl::StrCat("/api/v1/jobs/", id, "/cancel"), "{}", "application/json");
}

// The queue's calls answer where this build's service has them (the
// features /api/v1/info lists) and 501 naming what is missing otherwise.
TEST_F(HttpApi, QueueCallsFollowTheAdvertisedFeatures) {
  const v1::Job job = Submit(testing::SmallTetrahedronJob());
  AwaitEnd(job.id());
  const std::string info = Client().Get("/api/v1/info").body;
  const std::string base = absl::StrCat("/api/v1/jobs/", job.id());
  auto workers = Client().Get("/api/v1/workers");
  auto retry = Client().Post(base + "/retry", "{}", "application/json");
  auto events = Client().Get(base + "/events");
  auto priority = Client().Post(base + "/priority", R"({"priority":2})", "application/json");
  const std::pair<const char*, httplib::Response*> calls[] = {{"\"workers\"", &workers},
                                                              {"\"retry\"", &retry},
                                                              {"\"events\"", &events},
                                                              {"\"priority\"", &priority}};
  for (const auto& [feature, r] : calls) {
    if (info.find(feature) != std::string::npos) {
      // Answered by the service (retrying a succeeded job may be refused).
      EXPECT_NE(r->status, 501) << feature << " " << r->body;
      EXPECT_EQ(r->body.find("no such path"), std::string::npos);
    } else {
      EXPECT_EQ(r->status, 501) << feature << " " << r->body;
      EXPECT_NE(r->body.find("UNIMPLEMENTED"), std::string::npos);
    }
  }
  if (info.find("\"workers\"") == std::string::npos)
    EXPECT_NE(workers.body.find("no worker registry on this server"), std::string::npos);
  EXPECT_EQ(Client().Post(base + "/retry", "{}", "text/plain").status, 415);
}

TEST_F(HttpApi, MetricsPassPromtoolAndCountJobs) {
  const v1::Job a = Submit(testing::SmallTetrahedronJob());
  const v1::Job b = Submit(testing::SmallTetrahedronJob());
  AwaitEnd(a.id());
  AwaitEnd(b.id());
  auto metrics = Client("").Get("/metrics");
  ASSERT_EQ(metrics.status, 200);
  const std::string& text = metrics.body;
  EXPECT_NE(text.find("nimbus_jobs{kind=\"chaos_game\",state=\"succeeded\"} 2\n"),
            std::string::npos)
      << text;
  EXPECT_NE(
      text.find(
          "nimbus_grpc_calls_total{code=\"OK\",method=\"nimbus.v1.NimbusService/SubmitJob\"} 2"),
      std::string::npos);
  EXPECT_NE(text.find("nimbus_job_duration_seconds_count{kind=\"chaos_game\"} 2"),
            std::string::npos);
  std::ofstream(dir_ / "metrics.txt") << text;
  const std::string cmd = absl::StrCat("promtool check metrics < ", (dir_ / "metrics.txt").string(),
                                       " > ", (dir_ / "promtool.txt").string(), " 2>&1");
  EXPECT_EQ(std::system(cmd.c_str()), 0) << ReadAll(dir_ / "promtool.txt");
}

// The value of the series `series` (name and labels as Prometheus' text
// format writes them) in `text`; -1 when it is absent.
double SeriesValue(const std::string& text, const std::string& series) {
  for (absl::string_view line : absl::StrSplit(text, '\n'))
    if (absl::StartsWith(line, series + " "))
      return std::stod(std::string(line.substr(series.size() + 1)));
  return -1;
}

std::string StoreCalls(const char* call) {
  return absl::StrCat("nimbus_store_call_duration_seconds_count{call=\"", call, "\"}");
}

// Queued jobs at known priorities, behind two that hold both workers,
// counted by band (low 0-33, normal 34-66, high 67-100, as documented);
// and the store calls those submissions and reads made, timed by call.
TEST_F(HttpApi, QueueDepthByPriorityBandAndStoreCallLatency) {
  std::vector<std::string> ids;
  for (int i = 0; i < 2; ++i) ids.push_back(Submit(EndlessJob()).id());
  for (const std::string& id : ids) AwaitRunning(id);
  // Each band's edges: low 2, normal 2, high 3.
  for (int priority : {0, 33, 34, 66, 67, 90, 100}) {
    v1::SubmitJobRequest req;
    *req.mutable_spec() = EndlessJob();
    req.set_priority(priority);
    std::string body;
    ASSERT_TRUE(google::protobuf::util::MessageToJsonString(req, &body).ok());
    auto r = Client().Post("/api/v1/jobs", body, "application/json");
    ASSERT_EQ(r.status, 200) << r.body;
    ids.push_back(Parse<v1::SubmitJobResponse>(r.body).job().id());
  }
  const std::string before = Client("").Get("/metrics").body;
  const auto depth = [](const std::string& text, const char* band) {
    return SeriesValue(text, absl::StrCat("nimbus_queue_depth{priority_band=\"", band, "\"}"));
  };
  EXPECT_EQ(depth(before, "low"), 2) << before;
  EXPECT_EQ(depth(before, "normal"), 2);
  EXPECT_EQ(depth(before, "high"), 3);
  EXPECT_EQ(SeriesValue(before, StoreCalls("Create")), 9);
  EXPECT_GT(SeriesValue(before, StoreCalls("Get")), 0);  // AwaitRunning's reads
  EXPECT_GE(SeriesValue(before, StoreCalls("ClaimNext")), 2);
  EXPECT_GE(SeriesValue(before, StoreCalls("List")), 1);  // the scrape's own
  EXPECT_EQ(SeriesValue(before, StoreCalls("SetPriority")), -1);

  // Five reads and one move from low to high.
  for (int i = 0; i < 5; ++i) Get(ids[2]);
  ASSERT_EQ(Client()
                .Post(absl::StrCat("/api/v1/jobs/", ids[2], "/priority"), R"({"priority":100})",
                      "application/json")
                .status,
            200);
  const std::string after = Client("").Get("/metrics").body;
  EXPECT_EQ(depth(after, "low"), 1) << after;
  EXPECT_EQ(depth(after, "normal"), 2);
  EXPECT_EQ(depth(after, "high"), 4);
  EXPECT_GE(SeriesValue(after, StoreCalls("Get")), SeriesValue(before, StoreCalls("Get")) + 5);
  EXPECT_EQ(SeriesValue(after, StoreCalls("SetPriority")), 1);
  EXPECT_NE(
      after.find("nimbus_store_call_duration_seconds_bucket{call=\"SetPriority\",le=\"+Inf\"} 1"),
      std::string::npos);
  std::ofstream(dir_ / "metrics.txt") << after;
  const std::string cmd = absl::StrCat("promtool check metrics < ", (dir_ / "metrics.txt").string(),
                                       " > ", (dir_ / "promtool.txt").string(), " 2>&1");
  EXPECT_EQ(std::system(cmd.c_str()), 0) << ReadAll(dir_ / "promtool.txt");
  for (const std::string& id : ids)
    Client().Post(absl::StrCat("/api/v1/jobs/", id, "/cancel"), "{}", "application/json");
}

// The HTTP port speaks HTTPS with the gRPC port's certificate, and follows
// its rule that a port beyond loopback needs tokens.
TEST(HttpTls, SameCertificateAndLoopbackRule) {
  testing::TempDir dir;
  auto pki = testing::MakeTestPki(dir / "pki");
  ASSERT_TRUE(pki.ok()) << pki.status();
  testing::NimbusdProcess server(dir / "data", {"--log-level", "warn", "--min-free-disk-mib", "0",
                                                "--tls-cert", pki->server_cert.string(),
                                                "--tls-key", pki->server_key.string(), "--http",
                                                "127.0.0.1:0", "--http-port-file",
                                                (dir / "http_port").string()});
  ASSERT_TRUE(server.Start().ok());
  const int port = std::stoi(ReadAll(dir / "http_port"));
  httplib::SSLClient tls("127.0.0.1", port);
  tls.set_ca_cert_path(pki->ca_cert.c_str());
  tls.enable_server_certificate_verification(true);
  auto ok = Http::Of(tls.Get("/api/v1/jobs"));
  EXPECT_EQ(ok.status, 200) << ok.body;
  httplib::SSLClient stranger("127.0.0.1", port);
  stranger.set_ca_cert_path(pki->other_ca_cert.c_str());
  stranger.enable_server_certificate_verification(true);
  EXPECT_EQ(Http::Of(stranger.Get("/api/v1/jobs")).status, -1);
  httplib::Client plain("127.0.0.1", port);
  plain.set_read_timeout(5, 0);
  auto p = Http::Of(plain.Get("/api/v1/jobs"));
  EXPECT_NE(p.status, 200);
  server.Stop();

  // Beyond loopback without tokens nimbusd refuses to start.
  testing::NimbusdProcess open(dir / "data2", {"--log-level", "warn", "--http", "0.0.0.0:0",
                                               "--http-port-file", (dir / "p2").string()});
  open.set_log_file(dir / "open.log");
  EXPECT_FALSE(open.Start().ok());
  EXPECT_NE(ReadAll(dir / "open.log").find("refusing to listen on 0.0.0.0:0"), std::string::npos)
      << ReadAll(dir / "open.log");
}

// Two replicas on one PostgreSQL store: a job that replica B runs shows
// live (state, progress, previews) on replica A's HTTP port.
TEST(HttpReplicas, AJobRunningOnBShowsLiveOnA) {
  std::string why;
  testing::PostgresServer* pg = testing::PostgresServer::Shared(&why);
  if (!pg) GTEST_SKIP() << why;
  auto url = pg->NewDatabase();
  ASSERT_TRUE(url.ok()) << url.status();
  testing::TempDir dir;
  auto args = [&](const std::string& id) {
    return std::vector<std::string>{"--store",
                                    *url,
                                    "--results-dir",
                                    (dir / "results").string(),
                                    "--replica-id",
                                    id,
                                    "--workers",
                                    "1",
                                    "--threads-per-job",
                                    "1",
                                    "--log-level",
                                    "warn",
                                    "--min-free-disk-mib",
                                    "0",
                                    "--http",
                                    "127.0.0.1:0",
                                    "--http-port-file",
                                    (dir / (id + ".http")).string()};
  };
  testing::NimbusdProcess a(dir / "a", args("A")), b(dir / "b", args("B"));
  ASSERT_TRUE(a.Start().ok());
  ASSERT_TRUE(b.Start().ok());
  httplib::Client c("127.0.0.1", std::stoi(ReadAll(dir / "A.http")));
  c.set_read_timeout(60, 0);
  std::vector<std::string> ids;
  for (int i = 0; i < 2; ++i) {
    auto r = Http::Of(c.Post("/api/v1/jobs", SubmitBody(EndlessJob()), "application/json"));
    ASSERT_EQ(r.status, 200) << r.body;
    ids.push_back(Parse<v1::SubmitJobResponse>(r.body).job().id());
  }
  // One worker each: the two jobs run one on each replica.
  std::string on_b;
  for (int i = 0; i < 3000 && on_b.empty(); ++i) {
    auto list = Parse<v1::ListJobsResponse>(Http::Of(c.Get("/api/v1/jobs?state=RUNNING")).body);
    for (const v1::Job& j : list.jobs())
      if (absl::StartsWith(j.worker(), "B/") && j.progress().done() > 0) on_b = j.id();
    if (on_b.empty()) std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  ASSERT_FALSE(on_b.empty()) << "no job ran on replica B";
  uint64_t first_done = 0, last_done = 0;
  int previews = 0;
  size_t seen = 0;
  const std::string stream =
      absl::StrCat("/api/v1/jobs/", on_b, "/stream?preview_resolution=16&preview_interval=0.2");
  ReadEvents(c, stream, [&](const auto& events) {
    for (; seen < events.size(); ++seen) {
      const auto& [name, data] = events[seen];
      if (name == "preview") ++previews;
      if (name != "job") continue;
      const v1::Job j = Parse<v1::Job>(data);
      EXPECT_TRUE(absl::StartsWith(j.worker(), "B/"));
      if (first_done == 0) first_done = j.progress().done();
      last_done = j.progress().done();
    }
    return previews >= 2 && last_done > first_done;
  });
  EXPECT_GE(previews, 2);
  EXPECT_GT(last_done, first_done);
  auto png = Http::Of(c.Get(absl::StrCat("/api/v1/jobs/", on_b, "/preview.png?resolution=16")));
  EXPECT_EQ(png.status, 200);
  for (const std::string& id : ids)
    Http::Of(c.Post(absl::StrCat("/api/v1/jobs/", id, "/cancel"), "{}", "application/json"));
}

}  // namespace
}  // namespace nimbus
