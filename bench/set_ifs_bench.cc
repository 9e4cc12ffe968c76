// Condensation-set figures at the reference description's resolution (256^3): voxelising the
// cow sketch, preparing the median maps, and one random set-iteration of the
// cow cloud (cow + random balls inside it, p = 2/3 and 1/3).
#include <benchmark/benchmark.h>
#include <tbb/global_control.h>
#include <time.h>

#include <cstdio>
#include <cstdlib>
#include <memory>
#include <optional>

#include "core/base/random.h"
#include "core/sets/feature_transform.h"
#include "core/io/mesh_io.h"
#include "core/sets/set_ifs.h"
#include "core/sets/shapes.h"
#include "core/sets/voxelize.h"

namespace nimbus {
namespace {

constexpr int kResolution = 256;

GridFrame Frame() { return {{kResolution, kResolution, kResolution}, {{-1, -1, -1}, {1, 1, 1}}}; }

const TriangleMesh& Cow() {
  static const TriangleMesh mesh = [] {
    absl::StatusOr<TriangleMesh> m = LoadMesh(NIMBUS_SOURCE_DIR "/examples/meshes/cow.obj");
    if (!m.ok()) {
      std::fprintf(stderr, "%s\n", std::string(m.status().message()).c_str());
      std::abort();
    }
    return *std::move(m);
  }();
  return mesh;
}

struct CowCloud {
  VoxelSet cow, balls;
  SetIfs ifs;
};

// The two sketches and the IFS, built once.
const CowCloud& Cloud() {
  static const std::unique_ptr<CowCloud> cloud = [] {
    auto c = std::make_unique<CowCloud>();
    const GridFrame f = Frame();
    VoxelizeOptions vo;
    vo.fit = true;
    c->cow = VoxelizeMesh(Cow(), f, vo)->interior;
    RandomBallsOptions bo;
    bo.count = 40;
    bo.min_radius = 0.05;  // 6 to 15 voxels
    bo.max_radius = 0.12;
    bo.seed = 7;
    c->balls = *RandomBallsInside(c->cow, f, bo);
    c->ifs = {f, {*MakeMedianMap(f, c->cow), *MakeMedianMap(f, c->balls)}, {2.0 / 3, 1.0 / 3}, {}};
    return c;
  }();
  return *cloud;
}

void BM_VoxelizeCow(benchmark::State& state) {
  const GridFrame f = Frame();
  VoxelizeOptions o;
  o.fit = true;
  int64_t voxels = 0;
  for (auto _ : state) {
    absl::StatusOr<VoxelizeResult> r = VoxelizeMesh(Cow(), f, o);
    voxels = r->interior.Count();
    benchmark::DoNotOptimize(voxels);
  }
  state.counters["voxels"] = double(voxels);
}
BENCHMARK(BM_VoxelizeCow)->Unit(benchmark::kMillisecond)->Iterations(5);

void BM_PrepareMedianMap(benchmark::State& state) {
  const CowCloud& c = Cloud();
  for (auto _ : state) benchmark::DoNotOptimize(MakeMedianMap(c.ifs.frame, c.cow));
}
BENCHMARK(BM_PrepareMedianMap)->Unit(benchmark::kMillisecond)->Iterations(3);

double ProcessCpuSeconds() {
  timespec t;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return double(t.tv_sec) + 1e-9 * double(t.tv_nsec);
}

// Wall time per benchmark iteration covers `kSteps` set-iterations; the
// counters give the per-set-iteration figures. The argument is the thread
// count (0: TBB's default). cpu_ms_per_set_iteration is the process's CPU
// time: on one thread it hardly depends on what else the machine runs, so
// it is the figure to compare on a loaded machine.
void BM_CowCloudSetIteration(benchmark::State& state) {
  const CowCloud& c = Cloud();
  std::optional<tbb::global_control> threads;
  if (state.range(0) > 0)
    threads.emplace(tbb::global_control::max_allowed_parallelism, size_t(state.range(0)));
  constexpr uint64_t kSteps = 24;
  double seconds = 0, nearest = 0, maps = 0, counting = 0, voxels = 0, cpu = 0;
  uint64_t steps = 0, seed = 1;
  for (auto _ : state) {
    CountGrid counts(c.ifs.frame.resolution);
    SetIfsRunOptions o;
    o.warmup = 0;
    o.iterations = kSteps;
    o.seed = seed++;
    o.start = c.cow;  // already on the attractor: every step is typical
    const double cpu0 = ProcessCpuSeconds();
    const absl::StatusOr<SetIfsRunStats> s = RunSetIfs(c.ifs, o, counts);
    cpu += ProcessCpuSeconds() - cpu0;
    seconds += s->seconds;
    nearest += s->nearest_seconds;
    maps += s->map_seconds;
    counting += s->count_seconds;
    voxels += double(s->voxels_counted);
    steps += s->iterations;
  }
  state.counters["ms_per_set_iteration"] = 1e3 * seconds / double(steps);
  state.counters["cpu_ms_per_set_iteration"] = 1e3 * cpu / double(steps);
  state.counters["nearest_share"] = nearest / seconds;
  state.counters["map_ms"] = 1e3 * maps / double(steps);
  state.counters["count_ms"] = 1e3 * counting / double(steps);
  state.counters["voxels_per_set"] = voxels / double(steps);
}
BENCHMARK(BM_CowCloudSetIteration)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond)->Iterations(4);

// Not a timing: a fingerprint of 24 set-iterations (every set, in order),
// printed so that a speed change can be checked to leave results unchanged.
void BM_CowCloudFingerprint(benchmark::State& state) {
  const CowCloud& c = Cloud();
  uint64_t hash = 0;
  for (auto _ : state) {
    CountGrid counts(c.ifs.frame.resolution);
    SetIfsRunOptions o;
    o.warmup = 0;
    o.iterations = 24;
    o.seed = 1;
    o.start = c.cow;
    o.observe_every = 1;
    hash = 0;
    o.observer = [&](uint64_t k, const CountGrid&, const VoxelSet& set) {
      for (uint64_t w : set.words()) hash = Mix64(hash ^ w) + k;
    };
    benchmark::DoNotOptimize(RunSetIfs(c.ifs, o, counts));
  }
  std::printf("cow_cloud fingerprint of 24 set-iterations: %016llx\n",
              static_cast<unsigned long long>(hash));
}
BENCHMARK(BM_CowCloudFingerprint)->Unit(benchmark::kMillisecond)->Iterations(1);

void BM_FeatureTransformWholeLattice(benchmark::State& state) {
  const CowCloud& c = Cloud();
  FeatureField field;
  for (auto _ : state) {
    benchmark::DoNotOptimize(
        ComputeFeatureTransform(c.balls, c.ifs.frame.VoxelSize(), {}, field, nullptr));
  }
  state.counters["voxels"] = double(c.ifs.frame.resolution.Volume());
}
BENCHMARK(BM_FeatureTransformWholeLattice)->Unit(benchmark::kMillisecond)->Iterations(3);

}  // namespace
}  // namespace nimbus

BENCHMARK_MAIN();
