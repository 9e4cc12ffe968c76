// How a real nimbusd on loopback feels to its users. A nimbusd child
// process serves each figure, and the client library calls it:
//   1. SubmitJob to the first preview on a watch stream (target < 250 ms);
//   2. the cost of 3 watchers taking a preview each second, as job wall
//      time against the same job with no preview watcher (target <= 5 %);
//   3. FetchResult of a ~64 MB result file (target <= 60 ms), beside the
//      floor: the same stream read with the raw stub and thrown away;
//   4. the share of job time spent writing the VDB (stat write_ms).
// Prints figures; asserts nothing about speed.
//
// Usage: responsiveness_bench [REPEATS [fetch]]   (default 3; `fetch` runs
// only figures 3 and 4)
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <thread>
#include <vector>

#include <grpcpp/grpcpp.h>

#include "client/nimbus_client.h"
#include "core/base/heap_tuning.h"
#include "nimbus/v1/nimbus_service.grpc.pb.h"
#include "proto/spec_io.h"
#include "tests/support/nimbusd_process.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

using Clock = std::chrono::steady_clock;
double Ms(Clock::duration d) { return std::chrono::duration<double, std::milli>(d).count(); }

double Median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0 : v[v.size() / 2];
}

v1::JobSpec LoadExample(const std::string& name) {
  auto spec = spec::LoadSpecFile(testing::SourcePath("examples/" + name));
  if (!spec.ok()) {
    std::fprintf(stderr, "cannot load %s: %s\n", name.c_str(), spec.status().ToString().c_str());
    std::exit(1);
  }
  return *spec;
}

v1::JobSpec Tetrahedron(uint64_t iterations) {
  v1::JobSpec spec = LoadExample("sierpinski_tetrahedron.json");
  spec.mutable_chaos_game()->set_iterations(iterations);
  spec.set_no_cache(true);  // every job here must really run
  return spec;
}

double JobSeconds(const v1::Job& job) {
  const auto ms = [](const google::protobuf::Timestamp& t) {
    return double(t.seconds()) * 1e3 + double(t.nanos()) / 1e6;
  };
  return (ms(job.end_time()) - ms(job.start_time())) / 1e3;
}

// A watch that ends when the job does, taking previews at `interval`.
v1::Job WatchToEnd(client::NimbusClient& c, const std::string& id, uint32_t resolution,
                   double interval, int* previews = nullptr) {
  client::WatchOptions w;
  w.preview_resolution = resolution;
  w.preview_interval_seconds = interval;
  auto job = c.Watch(id, w, [previews](const v1::WatchJobResponse& r) {
    if (previews && r.has_preview()) ++*previews;
  });
  if (!job.ok()) {
    std::fprintf(stderr, "watch failed: %s\n", job.status().ToString().c_str());
    std::exit(1);
  }
  return *job;
}

void FirstPreview(client::NimbusClient& c, const std::string& address, int repeats) {
  // Cancels from inside the watch callback go through a client of their own.
  auto canceller = client::NimbusClient::Connect(address);
  std::vector<double> ms;
  for (int i = 0; i < repeats + 1; ++i) {
    const auto t0 = Clock::now();
    auto job = c.Submit(Tetrahedron(uint64_t{20} << 30));
    if (!job.ok()) std::exit(1);
    double first = -1;
    client::WatchOptions w;
    w.preview_resolution = 64;
    w.preview_interval_seconds = 0.1;
    (void)c.Watch(job->id(), w, [&](const v1::WatchJobResponse& r) {
      if (r.has_preview() && first < 0) {
        first = Ms(Clock::now() - t0);
        (void)canceller->Cancel(job->id());
      }
    });
    if (i > 0) ms.push_back(first);  // the first run warms the process up
  }
  std::printf("submit -> first preview (64^3, tetrahedron 256^3): median %.0f ms, max %.0f ms "
              "over %d runs (target < 250 ms)\n",
              Median(ms), *std::max_element(ms.begin(), ms.end()), repeats);
}

void WatcherCost(const std::string& address, int repeats) {
  auto c = client::NimbusClient::Connect(address);
  std::vector<double> alone, watched;
  int previews = 0;
  const uint64_t iterations = uint64_t{1} << 30;
  for (int i = 0; i < repeats; ++i) {
    auto a = c->Submit(Tetrahedron(iterations));
    alone.push_back(JobSeconds(WatchToEnd(*c, a->id(), 0, 1.0)));
    auto b = c->Submit(Tetrahedron(iterations));
    std::vector<std::thread> watchers;
    std::vector<int> counts(3, 0);
    for (int k = 0; k < 3; ++k)
      watchers.emplace_back([&, k] {
        auto own = client::NimbusClient::Connect(address);
        WatchToEnd(*own, b->id(), 128, 1.0, &counts[size_t(k)]);
      });
    for (auto& t : watchers) t.join();
    auto done = c->Get(b->id());
    watched.push_back(JobSeconds(*done));
    for (int n : counts) previews += n;
  }
  const double a = Median(alone), w = Median(watched);
  std::printf("3 watchers at 1 preview/s (128^3): job %.2f s vs %.2f s alone: %+.1f %% "
              "(%d previews delivered; target <= 5 %%)\n",
              w, a, 100 * (w / a - 1), previews);
}

// Best time to stream job `id`'s result with the raw stub, keeping nothing:
// what gRPC on loopback costs before the client writes or hashes a byte.
double StreamFloorMs(const std::string& address, const std::string& id, int repeats) {
  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(64 << 20);
  args.SetInt(GRPC_ARG_HTTP2_STREAM_LOOKAHEAD_BYTES, 16 << 20);
  auto stub = v1::NimbusService::NewStub(
      grpc::CreateCustomChannel(address, grpc::InsecureChannelCredentials(), args));
  std::vector<double> ms;
  for (int i = 0; i < repeats; ++i) {
    const auto t0 = Clock::now();
    grpc::ClientContext ctx;
    v1::FetchResultRequest req;
    req.set_job_id(id);
    auto reader = stub->FetchResult(&ctx, req);
    v1::FetchResultResponse chunk;
    while (reader->Read(&chunk)) {
    }
    if (!reader->Finish().ok()) std::exit(1);
    ms.push_back(Ms(Clock::now() - t0));
  }
  return *std::min_element(ms.begin(), ms.end());
}

void FetchAndWriteShare(client::NimbusClient& c, const std::string& address,
                        const std::filesystem::path& dir, int repeats) {
  // A dense 326^3 cloud: every voxel active, so the file is ~64.6 MB, just
  // above the 64 MB the target names.
  v1::JobSpec spec = LoadExample("cumulus.json");
  spec.mutable_fractal_field()->clear_shape();
  spec.mutable_grid()->clear_resolution();
  spec.mutable_grid()->add_resolution(326);
  spec.set_no_cache(true);
  auto job = c.Submit(spec);
  const v1::Job done = WatchToEnd(c, job->id(), 0, 1.0);
  const double mb = double(done.result().size_bytes()) / 1e6;
  std::vector<double> ms;
  for (int i = 0; i < repeats; ++i) {
    const std::filesystem::path out = dir / "fetched.vdb";
    std::filesystem::remove(out);
    const auto t0 = Clock::now();
    if (!c.Fetch(done.id(), out).ok()) std::exit(1);
    ms.push_back(Ms(Clock::now() - t0));
  }
  const double best = *std::min_element(ms.begin(), ms.end());
  std::printf("FetchResult of %.1f MB on loopback (sha256 checked, written to disk): best %.0f "
              "ms, median %.0f ms, %.0f MB/s (target <= 60 ms for 64 MB)\n",
              mb, best, Median(ms), mb / best * 1e3);
  std::printf("  floor: the same stream read and discarded (raw stub): best %.0f ms\n",
              StreamFloorMs(address, done.id(), repeats));
  const auto share = [](const v1::Job& j) {
    auto it = j.stats().find("write_ms");
    return it == j.stats().end() ? -1.0 : double(it->second) / 1e3 / JobSeconds(j) * 100;
  };
  std::printf("VDB write share: dense 326^3 cloud %.0f %% of %.2f s", share(done), JobSeconds(done));
  auto t = c.Submit(Tetrahedron(uint64_t{1} << 30));
  const v1::Job tet = WatchToEnd(c, t->id(), 0, 1.0);
  std::printf("; tetrahedron 256^3 (1.07e9 points) %.0f %% of %.2f s\n", share(tet),
              JobSeconds(tet));
}

}  // namespace
}  // namespace nimbus

int main(int argc, char** argv) {
  // As the nimbus CLI does: the fetch figure is what its downloads cost.
  nimbus::KeepFreedHeapForReuse();
  const int repeats = argc > 1 ? std::max(1, std::atoi(argv[1])) : 3;
  char dir_template[] = "/tmp/nimbus_resp_XXXXXX";
  const std::filesystem::path dir = mkdtemp(dir_template);
  nimbus::testing::NimbusdProcess server(dir / "data", {"--workers", "1"});
  if (auto st = server.Start(); !st.ok()) {
    std::fprintf(stderr, "cannot start nimbusd: %s\n", st.ToString().c_str());
    return 1;
  }
  const std::string address = "127.0.0.1:" + std::to_string(server.port());
  auto client = nimbus::client::NimbusClient::Connect(address);
  std::printf("responsiveness_bench: nimbusd on %s, 1 worker, %u hardware threads\n",
              address.c_str(), std::thread::hardware_concurrency());
  const bool fetch_only = argc > 2 && std::string(argv[2]) == "fetch";
  if (!fetch_only) {
    nimbus::FirstPreview(*client, address, repeats);
    nimbus::WatcherCost(address, repeats);
  }
  nimbus::FetchAndWriteShare(*client, address, dir, repeats);
  server.Stop();
  std::filesystem::remove_all(dir);
  return 0;
}
