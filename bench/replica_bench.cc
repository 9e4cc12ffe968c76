// Throughput and claim latency of nimbusd replicas on one PostgreSQL queue
// (a private server, as the tests start). Prints:
//  - jobs per second through submit -> claim -> run -> complete for tiny
//    jobs, on 1 and on 3 replicas (2 workers each, parallel clients);
//  - the claim latency after a submit: start_time - create_time of jobs
//    submitted one at a time to idle replicas (median, p90, max);
//  - the store-level cross-replica wake: a submit on one store handle until
//    another handle, woken by LISTEN/NOTIFY, has claimed it.
// Figures, not assertions.
//   build/bin/replica_bench [tiny jobs per run, default 300]
#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "client/nimbus_client.h"
#include "proto/spec_io.h"
#include "server/job_store.h"
#include "tests/support/nimbusd_process.h"
#include "tests/support/postgres_server.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

using Clock = std::chrono::steady_clock;

double Ms(Clock::duration d) { return std::chrono::duration<double, std::milli>(d).count(); }

int64_t MsOf(const google::protobuf::Timestamp& t) {
  return t.seconds() * 1000 + t.nanos() / 1'000'000;
}

v1::JobSpec Tiny() {
  auto spec = spec::LoadSpecFile(std::string(NIMBUS_SOURCE_DIR) +
                                 "/examples/sierpinski_tetrahedron.json");
  if (!spec.ok()) {
    std::fprintf(stderr, "%s\n", spec.status().ToString().c_str());
    std::exit(1);
  }
  spec->mutable_grid()->set_resolution(0, 16);
  spec->mutable_chaos_game()->set_iterations(20'000);
  return *spec;
}

struct Cluster {
  testing::TempDir dir;
  std::vector<std::unique_ptr<testing::NimbusdProcess>> replicas;
  std::vector<std::unique_ptr<client::NimbusClient>> clients;

  bool Start(const std::string& url, int n) {
    for (int i = 0; i < n; ++i) {
      replicas.push_back(std::make_unique<testing::NimbusdProcess>(
          dir / ("data-" + std::to_string(i)),
          std::vector<std::string>{"--store", url, "--results-dir", (dir / "results").string(),
                                   "--replica-id", "bench" + std::to_string(i), "--workers", "2",
                                   "--threads-per-job", "1", "--min-free-disk-mib", "0",
                                   "--log-level", "warn"}));
      if (!replicas.back()->Start().ok()) return false;
      clients.push_back(client::NimbusClient::Connect(replicas.back()->target()));
      if (!clients.back()->WaitForReady(20).ok()) return false;
    }
    return true;
  }
  ~Cluster() {
    for (auto& r : replicas) r->Stop();
  }
};

// Waits until `ids` all ended; false on a failure or after two minutes.
bool AwaitAll(client::NimbusClient& c, const std::vector<std::string>& ids,
              std::vector<v1::Job>* out = nullptr) {
  const auto deadline = Clock::now() + std::chrono::minutes(2);
  for (const std::string& id : ids) {
    while (true) {
      auto j = c.Get(id);
      if (j.ok() && j->state() == v1::JOB_STATE_SUCCEEDED) {
        if (out) out->push_back(*j);
        break;
      }
      if ((j.ok() && (j->state() == v1::JOB_STATE_FAILED ||
                      j->state() == v1::JOB_STATE_CANCELLED)) ||
          Clock::now() > deadline) {
        std::fprintf(stderr, "job %s did not succeed\n", id.c_str());
        return false;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
  }
  return true;
}

void Throughput(testing::PostgresServer& pg, int replicas, int jobs) {
  auto url = pg.NewDatabase();
  Cluster cluster;
  if (!url.ok() || !cluster.Start(*url, replicas)) {
    std::printf("%d replicas: could not start\n", replicas);
    return;
  }
  const v1::JobSpec spec = Tiny();
  constexpr int kClients = 6;
  std::vector<std::vector<std::string>> ids(kClients);
  const Clock::time_point t0 = Clock::now();
  std::vector<std::thread> threads;
  for (int t = 0; t < kClients; ++t) {
    threads.emplace_back([&, t] {
      auto c = client::NimbusClient::Connect(cluster.replicas[t % replicas]->target());
      for (int k = t; k < jobs; k += kClients) {
        auto j = c->Submit(spec);
        if (j.ok()) ids[t].push_back(j->id());
      }
    });
  }
  for (auto& th : threads) th.join();
  const double submit_ms = Ms(Clock::now() - t0);
  std::vector<std::string> all;
  for (auto& v : ids) all.insert(all.end(), v.begin(), v.end());
  if (!AwaitAll(*cluster.clients[0], all)) return;
  const double total_ms = Ms(Clock::now() - t0);
  std::printf("%d replica(s) x 2 workers: %zu tiny jobs in %.0f ms -> %.1f jobs/s "
              "(submits alone: %.1f/s)\n",
              replicas, all.size(), total_ms, all.size() * 1000.0 / total_ms,
              all.size() * 1000.0 / submit_ms);
}

void ClaimLatency(testing::PostgresServer& pg, int replicas, int samples) {
  auto url = pg.NewDatabase();
  Cluster cluster;
  if (!url.ok() || !cluster.Start(*url, replicas)) return;
  const v1::JobSpec spec = Tiny();
  std::vector<double> lat;
  for (int i = 0; i < samples; ++i) {
    // Idle workers everywhere: each submit goes to another replica in turn.
    std::this_thread::sleep_for(std::chrono::milliseconds(30));
    auto j = cluster.clients[i % replicas]->Submit(spec);
    if (!j.ok()) continue;
    std::vector<v1::Job> done;
    if (!AwaitAll(*cluster.clients[0], {j->id()}, &done)) return;
    lat.push_back(double(MsOf(done[0].start_time()) - MsOf(done[0].create_time())));
  }
  std::sort(lat.begin(), lat.end());
  std::printf("%d replica(s): claim latency after submit (start - create, ms, %zu jobs): "
              "median %.0f  p90 %.0f  max %.0f\n",
              replicas, lat.size(), lat[lat.size() / 2], lat[lat.size() * 9 / 10], lat.back());
}

// Store level: handle A submits, handle B (another "replica") is woken by
// the feed and claims. Time from before Create to after B's claim.
void FeedWake(testing::PostgresServer& pg, int samples) {
  auto url = pg.NewDatabase();
  if (!url.ok()) return;
  auto a = server::OpenPostgresJobStore(*url);
  auto b = server::OpenPostgresJobStore(*url);
  if (!a.ok() || !b.ok()) return;
  std::mutex mu;
  std::condition_variable cv;
  int wakes = 0;
  (*b)->SetChangeListener([&](const server::JobChange& c) {
    if (!c.claimable) return;
    std::lock_guard<std::mutex> lock(mu);
    ++wakes;
    cv.notify_all();
  });
  std::this_thread::sleep_for(std::chrono::milliseconds(300));  // listener connected
  std::vector<double> lat;
  for (int i = 0; i < samples; ++i) {
    int before;
    {
      std::lock_guard<std::mutex> lock(mu);
      before = wakes;
    }
    server::NewJob job;
    job.id = "feed-" + std::to_string(i);
    job.spec = "x";
    const Clock::time_point t0 = Clock::now();
    if (!(*a)->Create(job, 1).ok()) return;
    {
      std::unique_lock<std::mutex> lock(mu);
      cv.wait_for(lock, std::chrono::seconds(5), [&] { return wakes > before; });
    }
    auto claimed = (*b)->ClaimNext("b/w0", 2, 60'000);
    if (!claimed.ok() || !claimed->has_value()) return;
    lat.push_back(Ms(Clock::now() - t0));
  }
  (*b)->SetChangeListener(nullptr);
  std::sort(lat.begin(), lat.end());
  std::printf("store level: submit on replica A -> NOTIFY -> claim on replica B (ms, %zu): "
              "median %.2f  p90 %.2f  max %.2f\n",
              lat.size(), lat[lat.size() / 2], lat[lat.size() * 9 / 10], lat.back());
}

}  // namespace
}  // namespace nimbus

int main(int argc, char** argv) {
  const int jobs = argc > 1 ? std::atoi(argv[1]) : 300;
  std::string why;
  nimbus::testing::PostgresServer* pg = nimbus::testing::PostgresServer::Shared(&why);
  if (pg == nullptr) {
    std::printf("replica_bench: skipped: %s\n", why.c_str());
    return 0;
  }
  nimbus::FeedWake(*pg, 200);
  nimbus::ClaimLatency(*pg, 1, 30);
  nimbus::ClaimLatency(*pg, 3, 30);
  nimbus::Throughput(*pg, 1, jobs);
  nimbus::Throughput(*pg, 3, jobs);
  return 0;
}
