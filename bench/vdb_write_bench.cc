// Writing results with OpenVDB (WriteDensityVdb: every grid built from the
// counts, then OpenVDB's archive writer). Prints wall and process CPU time
// and the peak-RSS growth, for a 2D flame-like grid with colour and a dense
// cloud.
//
//   build/bin/vdb_write_bench [repeats]
#include <sys/resource.h>
#include <tbb/global_control.h>
#include <time.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <random>
#include <string>
#include <vector>

#include "core/io/vdb_io.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

double CpuSeconds() {
  timespec t{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return double(t.tv_sec) + 1e-9 * double(t.tv_nsec);
}

double PeakMb() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return double(u.ru_maxrss) / 1024.0;
}

// About 2/3 of a 1024x1024x1 grid hit, with colour: bench/flam3/flame6_2d's
// support (680 k voxels over 16 k leaves).
CountGrid ThinFlame() {
  CountGrid c({1024, 1024, 1}, /*with_color=*/true);
  std::mt19937 rng(1);
  for (int y = 0; y < 1024; ++y)
    for (int x = 0; x < 1024; ++x)
      if (rng() % 3 != 0)
        c.AddKey(CountGrid::WithColor(c.Key(x, y, 0), rng() % CountGrid::kColorScale),
                 1 + rng() % 50);
  return c;
}

// Every voxel of a 320^3 grid counted, no colour.
CountGrid DenseCloud() {
  CountGrid c({320, 320, 320});
  std::mt19937 rng(2);
  for (int x = 0; x < 320; ++x)
    for (int y = 0; y < 320; ++y)
      for (int z = 0; z < 320; ++z) c.Add(x, y, z, 1 + rng() % 1000);
  return c;
}

// Best wall and CPU seconds of `repeats` runs of `write`.
void Time(const char* label, int repeats, const std::function<void()>& write) {
  double wall = 1e30, cpu = 1e30;
  const double rss0 = PeakMb();
  for (int i = 0; i < repeats; ++i) {
    const double c0 = CpuSeconds();
    const auto t0 = std::chrono::steady_clock::now();
    write();
    wall = std::min(wall,
                    std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    cpu = std::min(cpu, CpuSeconds() - c0);
  }
  std::printf("  %-34s wall %6.3f s  cpu %6.3f s  peak RSS +%.0f MB\n", label, wall, cpu,
              PeakMb() - rss0);
}

void Case(const char* name, const CountGrid& counts, const DensityOptions& o, int repeats,
          const std::filesystem::path& dir) {
  GridFrame f;
  f.resolution = counts.resolution();
  f.bounds = {{-1, -1, -1}, {1, 1, 1}};
  std::printf("%s (%zu MB of counters):\n", name, counts.MemoryBytes() >> 20);
  Time("WriteDensityVdb (OpenVDB)", repeats, [&] {
    if (!WriteDensityVdb(dir / "s.vdb", counts, f, o, {}).ok()) std::exit(1);
  });
}

}  // namespace
}  // namespace nimbus

int main(int argc, char** argv) {
  using namespace nimbus;
  const int repeats = argc > 1 ? std::max(1, std::atoi(argv[1])) : 3;
  tbb::global_control threads(tbb::global_control::max_allowed_parallelism, 2);
  testing::TempDir dir;
  DensityOptions color;
  color.color = true;
  color.mapping = DensityMapping::kLog;
  Case("2D flame-like 1024x1024x1 with Cd, 2 threads", ThinFlame(), color, repeats, dir.path());
  Case("dense 320^3 cloud, 2 threads", DenseCloud(), DensityOptions{}, repeats, dir.path());
  return 0;
}
