// Fractal-field throughput: samples per second of grid evaluation for 3D
// and 4D fields, n-linear and pseudo n-cubic, 8 and 12 meshes, on 1 and 2
// threads; and, in the same run, libnoise's Perlin module with 8 octaves
// (one sample at a time, its only interface) when libnoise is installed.
// Counters: samples/s (items_per_second) and sample-octaves/s.
#include <benchmark/benchmark.h>
#include <tbb/task_arena.h>

#include <vector>

#include "core/field/field_grid.h"
#include "core/field/field_recipe.h"
#include "tests/support/field_oracles.h"

#ifdef NIMBUS_HAVE_LIBNOISE
#include <libnoise/noise.h>
#endif

namespace nimbus {
namespace {

constexpr int kSide = 128;  // 2M samples per 3D grid evaluation

FractalField MakeField(int dims, FieldInterpolation interp, int meshes) {
  // Cells halve from mesh to mesh down to one sample for the finest.
  const double base = double(uint64_t{1} << (meshes - 1));
  return FractalField(testing::SeriesParams(dims, 3, interp, {base, base, base, 4}, meshes, 0.7, 1));
}

// Args: dims, interpolation (0 linear, 1 pseudo-cubic), meshes, threads.
void BM_FieldGrid(benchmark::State& state) {
  const int dims = int(state.range(0));
  const auto interp = state.range(1) ? FieldInterpolation::kPseudoCubic : FieldInterpolation::kLinear;
  const int meshes = int(state.range(2));
  const int threads = int(state.range(3));
  const FractalField f = MakeField(dims, interp, meshes);
  FieldGrid g;
  g.count = {kSide, kSide, kSide};
  g.time = 0.3;
  std::vector<float> out(g.size());
  tbb::task_arena arena(threads);
  for (auto _ : state) {
    arena.execute([&] { (void)EvaluateFieldGrid(f, g, out.data()); });
    benchmark::DoNotOptimize(out.data());
  }
  const double samples = double(g.size()) * double(state.iterations());
  state.SetItemsProcessed(int64_t(samples));
  state.counters["sample_octaves_per_s"] =
      benchmark::Counter(samples * meshes, benchmark::Counter::kIsRate);
}
BENCHMARK(BM_FieldGrid)
    ->ArgNames({"dims", "cubic", "meshes", "threads"})
    ->ArgsProduct({{3, 4}, {0, 1}, {8, 12}, {1, 2}})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->MinTime(0.5);

#ifdef NIMBUS_HAVE_LIBNOISE
// libnoise Perlin, 8 octaves, on the same 3D grid size, one thread.
void BM_LibnoisePerlin8(benchmark::State& state) {
  noise::module::Perlin perlin;
  perlin.SetOctaveCount(8);
  perlin.SetNoiseQuality(noise::QUALITY_STD);
  const int side = 64;  // libnoise is slow: a smaller grid, the same rate
  double sink = 0;
  for (auto _ : state)
    for (int x = 0; x < side; ++x)
      for (int y = 0; y < side; ++y)
        for (int z = 0; z < side; ++z) sink += perlin.GetValue(x * 0.05, y * 0.05, z * 0.05);
  benchmark::DoNotOptimize(sink);
  const double samples = double(side) * side * side * double(state.iterations());
  state.SetItemsProcessed(int64_t(samples));
  state.counters["sample_octaves_per_s"] =
      benchmark::Counter(samples * 8, benchmark::Counter::kIsRate);
}
BENCHMARK(BM_LibnoisePerlin8)->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(0.5);
#else
void BM_LibnoisePerlin8_NotBuilt(benchmark::State& state) {
  for (auto _ : state) {
  }
  state.SkipWithError(
      "libnoise not found at configure time (apt-get install libnoise-dev): no comparison");
}
BENCHMARK(BM_LibnoisePerlin8_NotBuilt);
#endif

}  // namespace
}  // namespace nimbus
BENCHMARK_MAIN();
