// Chaos-game throughput in point updates per second (items_per_second),
// against two baselines: a naive loop writing through an OpenVDB accessor
// and a flat-array single-walker loop. The attractors are those of the
// examples (core/attractors.h).
#include <benchmark/benchmark.h>
#include <openvdb/openvdb.h>
#include <sys/resource.h>

#include <algorithm>
#include <memory>
#include <vector>

#include "tests/support/attractors.h"
#include "core/chaos/chaos_game.h"
#include "core/chaos/flame_program.h"
#include "core/chaos/image_plane.h"
#include "core/chaos/key_bins.h"
#include "core/base/cpu_dispatch.h"
#include "core/base/random.h"

namespace nimbus {
namespace {

uint64_t PeakRssBytes() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return uint64_t(u.ru_maxrss) * 1024;
}

// One full engine run per benchmark iteration: allocation, walk, merge.
// Arguments: threads, then the SIMD level (0 scalar, 1 AVX2, 2 AVX-512;
// lowered to what this CPU has, the label says which ran).
void RunEngine(benchmark::State& state, ChaosGameParams params) {
  const int threads = int(state.range(0));
  params.simd = std::min(SimdLevel(state.range(1)), DetectSimd());
  state.SetLabel(std::string(SimdName(std::min(*params.simd, DetectSimd()))));
  uint64_t engine_bytes = 0;
  for (auto _ : state) {
    auto game = ChaosGame::Create(params, threads);
    if (!game.ok()) {
      state.SkipWithError(std::string(game.status().message()).c_str());
      return;
    }
    (void)(*game)->Run(nullptr);
    engine_bytes = std::max(engine_bytes, (*game)->MemoryBytes());
    CountGrid counts = (*game)->TakeCounts();
    benchmark::DoNotOptimize(counts.AllocatedTiles());
  }
  state.SetItemsProcessed(int64_t(state.iterations() * params.iterations));
  state.counters["engine_bytes"] = double(engine_bytes);
  state.counters["estimate_bytes"] =
      double(ChaosGame::EstimateMemory(params, threads, sizeof(float)).peak());
  // What a job's status reports: the estimate refined by the pilot census.
  if (auto census = ChaosGame::Pilot(params, uint64_t{1} << 21, nullptr); census.ok())
    state.counters["pilot_estimate_bytes"] = double(
        ChaosGame::EstimateMemory(params, threads, sizeof(float), census->estimate).peak());
  state.counters["peak_rss_bytes"] = double(PeakRssBytes());
}

void BM_SierpinskiTetrahedron256(benchmark::State& state) {
  RunEngine(state, SierpinskiTetrahedronParams(256, uint64_t{1} << 27));
}
BENCHMARK(BM_SierpinskiTetrahedron256)
    ->ArgsProduct({{1, 2}, {0, 2}})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

// bench/compare_flam3.sh's 2D Sierpinski (bench/flam3/sierpinski_2d.json):
// three maps on a 1024 x 1024 x 1 grid, 2.1 * 10^8 points, as a volume and
// as a picture; the grid's 32 tiles take flat direct increments
// (core/chaos/tile_bins.h). CPU is the whole process's.
ChaosGameParams Sierpinski2DParams() {
  ChaosGameParams p;
  const double offsets[3][2] = {{0, 0}, {0.5, 0}, {0.25, 0.5}};
  for (const auto& o : offsets) {
    PointMap m;
    m.pre.m = {{{0.5, 0, 0, o[0]}, {0, 0.5, 0, o[1]}, {0, 0, 0, 0}}};
    p.ifs.maps.push_back(m);
  }
  p.ifs.probabilities = {1, 1, 1};
  p.frame = {{1024, 1024, 1}, {{-0.1, -0.1, -0.5}, {1.1, 1.1, 0.5}}};
  p.iterations = 209715200;
  p.seed = 1;
  return p;
}
void BM_Sierpinski2D(benchmark::State& state) { RunEngine(state, Sierpinski2DParams()); }
BENCHMARK(BM_Sierpinski2D)
    ->ArgsProduct({{1, 2}, {0, 1, 2}})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->MeasureProcessCPUTime()
    ->Iterations(1);
void BM_Sierpinski2DPicture(benchmark::State& state) {
  ChaosGameParams p = Sierpinski2DParams();
  p.image = MakeImagePlane({}, p.frame.bounds, 1024, 1024);
  RunEngine(state, p);
}
BENCHMARK(BM_Sierpinski2DPicture)
    ->ArgsProduct({{2}, {2}})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->MeasureProcessCPUTime()
    ->Iterations(1);

void BM_OctantCloud256(benchmark::State& state) {
  RunEngine(state, OctantCloudParams(256, uint64_t{1} << 28));
}
BENCHMARK(BM_OctantCloud256)
    ->ArgsProduct({{1, 2}, {0, 2}})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

void BM_FernVolume1024(benchmark::State& state) {
  RunEngine(state, FernVolumeParams(1024, uint64_t{1} << 30));
}
BENCHMARK(BM_FernVolume1024)
    ->ArgsProduct({{1, 2}, {0, 2}})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->Iterations(1);

// The binned fast path's two ways to use two threads on the 1024^3 fern:
// one grid per thread, merged at the end (0), or one shared grid (1, the
// default; core/chaos/shared_tiles.h). Same counts; compare CPU time and
// peak RSS as well as the rate.
void BM_FernSharedGrid(benchmark::State& state) {
  ChaosGameParams p = FernVolumeParams(1024, uint64_t{1} << 28);
  p.shared_grid = state.range(0) != 0;
  for (auto _ : state) {
    auto game = ChaosGame::Create(p, 2);
    if (!game.ok()) return state.SkipWithError("create failed");
    (void)(*game)->Run(nullptr);
    state.counters["engine_bytes"] = double((*game)->MemoryBytes());
    benchmark::DoNotOptimize((*game)->TakeCounts().AllocatedTiles());
  }
  state.SetItemsProcessed(int64_t(state.iterations() * p.iterations));
}
BENCHMARK(BM_FernSharedGrid)
    ->Arg(0)
    ->Arg(1)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->Iterations(1);

// The fast path's two sinks, voxels incremented at once (1) or binned by
// tile first (0), on attractors of growing extent, 2 threads, the best SIMD
// level: where ChaosGame's kDirectTiles should sit. Arguments: attractor
// (0 tetrahedron, 1 fern, 2 octant cloud), resolution, sink. `tiles` is the
// pilot's estimate of the tiles touched, which picks the sink by default.
void BM_FastPathSink(benchmark::State& state) {
  const int res = int(state.range(1));
  const uint64_t n = uint64_t{1} << 26;
  ChaosGameParams p = state.range(0) == 0   ? SierpinskiTetrahedronParams(res, n)
                      : state.range(0) == 1 ? FernVolumeParams(res, n)
                                            : OctantCloudParams(res, n);
  p.direct_increments = state.range(2) != 0;
  for (auto _ : state) {
    auto game = ChaosGame::Create(p, 2);
    if (!game.ok()) return state.SkipWithError("create failed");
    (void)(*game)->Run(nullptr);
    benchmark::DoNotOptimize((*game)->TakeCounts().AllocatedTiles());
  }
  state.SetItemsProcessed(int64_t(state.iterations() * p.iterations));
  if (auto census = ChaosGame::Pilot(p, uint64_t{1} << 18, nullptr); census.ok())
    state.counters["tiles"] = double(census->estimate);
  if (auto bricks = ChaosGame::Pilot(p, uint64_t{1} << 18, nullptr, {8, 8, 8}); bricks.ok())
    state.counters["hot_bytes"] = double(bricks->estimate * 512 * sizeof(uint32_t));
}
BENCHMARK(BM_FastPathSink)
    ->ArgsProduct({{0}, {256, 512, 1024}, {0, 1}})
    ->ArgsProduct({{1}, {256, 512}, {0, 1}})
    ->ArgsProduct({{2}, {128, 256}, {0, 1}})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->Iterations(1);

// bench/compare_flam3.sh's six-variation 2D flame (swirl, spherical, julia,
// sinusoidal, bubble, polar) at 1024 x 1024 x 1 with colour by map: the
// flame kernels at each SIMD level.
ChaosGameParams Flame6Params(uint64_t iterations) {
  using K = VariationKind;
  auto map = [](double a, double b, double c, double d, double e, double f,
                std::vector<VariationTerm> terms, double color) {
    PointMap m;
    m.pre.m = {{{a, b, 0, c}, {d, e, 0, f}, {0, 0, 0, 0}}};
    m.variations = std::move(terms);
    m.color = color;
    return m;
  };
  ChaosGameParams p;
  p.ifs.maps = {
      map(0.55, -0.25, 0.3, 0.25, 0.55, 0.1, {{K::kSwirl, 0.6, {}}, {K::kSpherical, 0.4, {}}}, 0.1),
      map(0.7, 0.2, -0.4, -0.2, 0.7, 0.5, {{K::kJulia, 0.8, {}}, {K::kSinusoidal, 0.2, {}}}, 0.5),
      map(0.5, 0, 0, 0, 0.5, -0.3, {{K::kBubble, 0.5, {}}, {K::kPolar, 0.5, {}}}, 0.9),
  };
  p.ifs.probabilities = {0.4, 0.35, 0.25};
  p.frame = {{1024, 1024, 1}, {{-2, -2, -0.5}, {2, 2, 0.5}}};
  p.iterations = iterations;
  p.seed = 1;
  p.color = {ColorMode::kMap, 0.5};
  return p;
}
void BM_Flame6Planar1024(benchmark::State& state) {
  RunEngine(state, Flame6Params(uint64_t{1} << 25));
}
BENCHMARK(BM_Flame6Planar1024)
    ->ArgsProduct({{2}, {0, 1, 2}})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->Iterations(1);

// The same flame drawn as a 1024 x 1024 picture looking down z
// (docs/images.md), whose rows fold into tiles: what the walk itself costs
// once the counts fit the cache.
void BM_Flame6Picture1024(benchmark::State& state) {
  ChaosGameParams p = Flame6Params(uint64_t{1} << 25);
  p.image = MakeImagePlane({}, p.frame.bounds, 1024, 1024);
  RunEngine(state, p);
}
BENCHMARK(BM_Flame6Picture1024)
    ->ArgsProduct({{1, 2}, {0, 1, 2}})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->Iterations(1);

// The flame kernel alone: one round of the second argument's walkers
// (one chunk's 64, or the block of four chunks ChaosGame steps together)
// of the six-variation flame per call, points kept bounded by the maps
// themselves; items are walker-steps.
void BM_Flame6KernelRound(benchmark::State& state) {
  const ChaosGameParams p = Flame6Params(1);
  const SimdLevel level = std::min(SimdLevel(state.range(0)), DetectSimd());
  const int n = int(state.range(1));
  state.SetLabel(std::string(SimdName(level)));
  const AliasTable table(p.ifs.probabilities);
  const FlameProgram program(p.ifs.maps, p.ifs.final_map, table, 1, p.color.blend);
  const flame::RoundFn round = FlameKernel(level);
  std::vector<uint64_t> words(size_t(program.program().words) * flame::kMaxWalkers);
  std::vector<uint32_t> group(p.ifs.maps.size() + 1);
  auto w = std::make_unique<flame::Walkers>();
  w->words = words.data();
  w->group = group.data();
  for (int k = 0; k < flame::kMaxWalkers; ++k) {
    const Rng rng(1, uint64_t(k));
    w->s0[k] = rng.state(0), w->s1[k] = rng.state(1), w->s2[k] = rng.state(2);
    w->s3[k] = rng.state(3);
    w->x[k] = 0.01 * k, w->y[k] = 0.1, w->z[k] = 0;
  }
  for (auto _ : state) {
    round(program.program(), *w, n);
    benchmark::DoNotOptimize(w->x[0]);
  }
  state.SetItemsProcessed(int64_t(state.iterations()) * n);
}
BENCHMARK(BM_Flame6KernelRound)
    ->ArgsProduct({{0, 1, 2}, {flame::kChunkWalkers, flame::kMaxWalkers}});

// The plot kernel alone (core/chaos/flame_plot.h): one round of 256 walkers
// of points spread over the picture of BM_Flame6Picture1024, projected and
// packed into keys with colour; items are walker-steps.
void BM_Flame6PlotRound(benchmark::State& state) {
  ChaosGameParams p = Flame6Params(1);
  p.image = MakeImagePlane({}, p.frame.bounds, 1024, 1024);
  const SimdLevel level = std::min(SimdLevel(state.range(0)), DetectSimd());
  state.SetLabel(std::string(SimdName(level)));
  const CountGrid grid(p.CountResolution(), true);
  const flame::PlotTarget target = MakePlotTarget(p, grid);
  const flame::PlotFn plot = FlamePlotter(level);
  auto w = std::make_unique<flame::Walkers>();
  Rng rng(2, 0);
  for (int k = 0; k < flame::kMaxWalkers; ++k) {
    w->x[k] = rng.Uniform(-2.5, 2.5);
    w->y[k] = rng.Uniform(-2.5, 2.5);
    w->z[k] = 0;
    w->col[k] = rng.Uniform();
  }
  auto out = std::make_unique<flame::Plotted>();
  for (auto _ : state) {
    plot(target, *w, false, flame::kMaxWalkers, out.get());
    benchmark::DoNotOptimize(out->key[0]);
    benchmark::DoNotOptimize(out->inside);
  }
  state.SetItemsProcessed(int64_t(state.iterations()) * flame::kMaxWalkers);
}
BENCHMARK(BM_Flame6PlotRound)->Arg(0)->Arg(1)->Arg(2);

// The general path's write side alone (core/chaos/key_bins.h): 2^24 keys
// with colour, uniform over a 1024 x 1024 picture's folded counters, added
// 64 lanes at a time as PlotRound adds them, then flushed; a fresh grid per
// iteration (its page faults count, as in a job). Items are keys.
void BM_KeyBinsPicture1024(benchmark::State& state) {
  const Int3 res = FoldedImageResolution(1024, 1024);
  const size_t capacity = size_t{1} << 18;  // what a picture job's workers get
  std::vector<uint64_t> keys(size_t{1} << 24);
  {
    const CountGrid grid(res, true);
    Rng rng(3, 0);
    for (uint64_t& k : keys) {
      const Int3 v = FoldedImageVoxel(int(rng.Next() % 1024), int(rng.Next() % 1024));
      k = CountGrid::WithColor(grid.Key(v.x, v.y, v.z), uint32_t(rng.Next() % 65536));
    }
  }
  for (auto _ : state) {
    CountGrid grid(res, true);
    KeyBins bins(grid, capacity, false);
    for (size_t i = 0; i < keys.size(); i += 64) bins.AddLanes(keys.data() + i, ~uint64_t{0});
    bins.Flush();
    benchmark::DoNotOptimize(grid.AllocatedTiles());
  }
  state.SetItemsProcessed(int64_t(state.iterations() * keys.size()));
}
BENCHMARK(BM_KeyBinsPicture1024)->Unit(benchmark::kMillisecond);

// A thin attractor on a huge grid: the pilot census and the memory it
// predicts against what the run really holds.
void BM_SierpinskiTetrahedron2048(benchmark::State& state) {
  const int threads = int(state.range(0));
  const ChaosGameParams params = SierpinskiTetrahedronParams(2048, uint64_t{1} << 30);
  uint64_t engine_bytes = 0, estimate = 0;
  for (auto _ : state) {
    auto census = ChaosGame::Pilot(params, uint64_t{1} << 21, nullptr);
    if (!census.ok()) return state.SkipWithError("pilot failed");
    estimate = ChaosGame::EstimateMemory(params, threads, sizeof(float), census->estimate).peak();
    auto game = ChaosGame::Create(params, threads);
    if (!game.ok()) return state.SkipWithError("create failed");
    (void)(*game)->Run(nullptr);
    engine_bytes = (*game)->MemoryBytes();
    benchmark::DoNotOptimize((*game)->TakeCounts().AllocatedTiles());
  }
  state.SetItemsProcessed(int64_t(state.iterations() * params.iterations));
  state.counters["engine_bytes"] = double(engine_bytes);
  state.counters["estimate_bytes"] = double(estimate);
  state.counters["geometric_estimate_bytes"] =
      double(ChaosGame::EstimateMemory(params, threads, sizeof(float)).peak());
  state.counters["peak_rss_bytes"] = double(PeakRssBytes());
}
BENCHMARK(BM_SierpinskiTetrahedron2048)
    ->Arg(2)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->Iterations(1);

// Baseline: one walker, each point written through an OpenVDB accessor.
void BM_NaiveOpenVdbAccessor256(benchmark::State& state) {
  openvdb::initialize();
  const ChaosGameParams p = SierpinskiTetrahedronParams(256, uint64_t{1} << 24);
  const AliasTable table(p.ifs.probabilities);
  const double inv = 256 / 2.0;
  for (auto _ : state) {
    auto grid = openvdb::Int32Grid::create(0);
    auto acc = grid->getAccessor();
    Rng rng(1, 0);
    Vec3 q{0.1, 0.2, 0.3};
    for (uint64_t i = 0; i < p.iterations; ++i) {
      q = p.ifs.maps[table.Sample(rng.Next())].pre.Apply(q);
      const openvdb::Coord c(int((q.x + 1) * inv), int((q.y + 1) * inv), int((q.z + 1) * inv));
      acc.setValue(c, acc.getValue(c) + 1);
    }
    benchmark::DoNotOptimize(grid->activeVoxelCount());
  }
  state.SetItemsProcessed(int64_t(state.iterations() * p.iterations));
}
BENCHMARK(BM_NaiveOpenVdbAccessor256)->Unit(benchmark::kMillisecond);

// Baseline: one walker, a dense uint32 array, no batching.
template <int kRes>
void FlatArray(benchmark::State& state, const ChaosGameParams& p) {
  const AliasTable table(p.ifs.probabilities);
  const Bounds& b = p.frame.bounds;
  const Vec3 vs = p.frame.VoxelSize();
  const double ix = 1 / vs.x, iy = 1 / vs.y, iz = 1 / vs.z;
  std::vector<uint32_t> counts(static_cast<size_t>(kRes) * kRes * kRes);
  for (auto _ : state) {
    Rng rng(1, 0);
    Vec3 q = 0.5 * (b.min + b.max);
    for (uint64_t i = 0; i < p.iterations; ++i) {
      q = p.ifs.maps[table.Sample(rng.Next())].pre.Apply(q);
      const double fx = (q.x - b.min.x) * ix, fy = (q.y - b.min.y) * iy, fz = (q.z - b.min.z) * iz;
      if (!(fx >= 0 && fx < kRes && fy >= 0 && fy < kRes && fz >= 0 && fz < kRes)) continue;
      ++counts[(size_t(fx) * kRes + size_t(fy)) * kRes + size_t(fz)];
    }
    benchmark::DoNotOptimize(counts.data());
  }
  state.SetItemsProcessed(int64_t(state.iterations() * p.iterations));
}
void BM_FlatArraySingleWalkerSierpinski256(benchmark::State& state) {
  FlatArray<256>(state, SierpinskiTetrahedronParams(256, uint64_t{1} << 26));
}
BENCHMARK(BM_FlatArraySingleWalkerSierpinski256)->Unit(benchmark::kMillisecond);
void BM_FlatArraySingleWalkerOctantCloud256(benchmark::State& state) {
  FlatArray<256>(state, OctantCloudParams(256, uint64_t{1} << 26));
}
BENCHMARK(BM_FlatArraySingleWalkerOctantCloud256)->Unit(benchmark::kMillisecond);
void BM_FlatArraySingleWalkerFern1024(benchmark::State& state) {
  FlatArray<1024>(state, FernVolumeParams(1024, uint64_t{1} << 26));
}
BENCHMARK(BM_FlatArraySingleWalkerFern1024)->Unit(benchmark::kMillisecond)->Iterations(1);

}  // namespace
}  // namespace nimbus

BENCHMARK_MAIN();
