// Cancel latency of every long core computation: how long an engine keeps
// running after its interrupter starts answering "stop". The server's
// CancelJob and SIGTERM drain wait on exactly this, and the hardening rule
// is "at least every ~10 ms of work".
//
// For each engine the bench times one full run (T), then cancels at 10 %,
// 30 %, 50 %, 70 % and 90 % of T and prints the worst and the median time
// from the cancel request to the engine's return. Figures, not assertions:
// tests/core/cancel_cadence_test.cc checks that every engine stops.
//   build/bin/cancel_latency_bench [resolution, default 256]
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <string>
#include <vector>

#include "core/base/interrupter.h"
#include "core/chaos/chaos_game.h"
#include "core/io/mesh_io.h"
#include "core/sets/feature_transform.h"
#include "core/sets/set_ifs.h"
#include "core/sets/set_maps.h"
#include "core/sets/shapes.h"
#include "core/sets/voxelize.h"

namespace nimbus {
namespace {

using Clock = std::chrono::steady_clock;

// Says "stop" from a fixed instant on, and remembers that instant.
class DeadlineInterrupter final : public Interrupter {
 public:
  explicit DeadlineInterrupter(Clock::time_point deadline) : deadline_(deadline) {}
  bool WasInterrupted(uint64_t, uint64_t) override { return Clock::now() >= deadline_; }
  Clock::time_point deadline() const { return deadline_; }

 private:
  Clock::time_point deadline_;
};

double Ms(Clock::duration d) { return std::chrono::duration<double, std::milli>(d).count(); }

using Engine = std::function<bool(Interrupter*)>;  // true when it ran to the end

void Measure(const char* name, const Engine& run) {
  const Clock::time_point t0 = Clock::now();
  if (!run(nullptr)) {
    std::printf("%-28s failed without a cancel\n", name);
    return;
  }
  const Clock::duration full = Clock::now() - t0;
  std::vector<double> latencies;
  for (double f : {0.1, 0.3, 0.5, 0.7, 0.9}) {
    const Clock::time_point start = Clock::now();
    DeadlineInterrupter intr(start + std::chrono::duration_cast<Clock::duration>(full * f));
    const bool finished = run(&intr);
    const Clock::time_point end = Clock::now();
    latencies.push_back(finished ? 0.0 : std::max(0.0, Ms(end - intr.deadline())));
  }
  std::sort(latencies.begin(), latencies.end());
  std::printf("%-28s full %8.1f ms   cancel latency: median %6.2f ms  worst %6.2f ms\n", name,
              Ms(full), latencies[latencies.size() / 2], latencies.back());
}

std::string Source(const char* rel) { return std::string(NIMBUS_SOURCE_DIR) + "/" + rel; }

}  // namespace
}  // namespace nimbus

int main(int argc, char** argv) {
  using namespace nimbus;
  const int n = argc > 1 ? std::atoi(argv[1]) : 256;
  const GridFrame frame{{n, n, n}, {{-1, -1, -1}, {1, 1, 1}}};
  std::printf("cancel latency at %d^3 (resolution as argv[1])\n", n);

  VoxelizeOptions fit;
  fit.fit = true;
  const absl::StatusOr<TriangleMesh> cow = LoadMesh(Source("examples/meshes/cow.obj"));
  const absl::StatusOr<TriangleMesh> suzanne = LoadMesh(Source("examples/meshes/suzanne.obj"));
  if (!cow.ok() || !suzanne.ok()) {
    std::printf("meshes missing: %s\n", std::string(cow.status().message()).c_str());
    return 1;
  }
  Measure("voxelize cow (ray vote)", [&](Interrupter* i) {
    return VoxelizeMesh(*cow, frame, fit, i).ok();
  });
  Measure("voxelize suzanne", [&](Interrupter* i) {
    return VoxelizeMesh(*suzanne, frame, fit, i).ok();
  });
  const VoxelSet sphere = *SphereSet(frame, {0, 0, 0}, 0.4);
  const VoxelSet box = *BoxSet(frame, {{0.2, 0.1, -0.3}, {0.8, 0.7, 0.3}});
  Measure("feature transform", [&](Interrupter* i) {
    return ComputeFeatureTransform(sphere, frame.VoxelSize(), i).ok();
  });
  Measure("median", [&](Interrupter* i) { return Median(sphere, box, frame, {}, i).ok(); });
  Measure("median map (precompute)", [&](Interrupter* i) {
    return MakeMedianMap(frame, sphere, {}, i).ok();
  });
  const SetIfs ifs{frame, {*MakeMedianMap(frame, sphere), *MakeMedianMap(frame, box)}, {}, {}};
  Measure("set IFS, 24 iterations", [&](Interrupter* i) {
    SetIfsRunOptions o;
    o.iterations = 16;
    o.warmup = 8;
    CountGrid counts(frame.resolution);
    return RunSetIfs(ifs, o, counts, i).ok();
  });
  return 0;
}
