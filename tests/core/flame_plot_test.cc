// The flame plot kernels (core/chaos/flame_plot.h): the scalar kernel
// gives every point the key the engine's Key, Project and Voxel compose
// (tests/support/plot_oracle.h), and the AVX2 and AVX-512 kernels give the
// scalar kernel's keys and masks bit for bit, on grids (3D and folded 2D)
// and pictures (orthographic and perspective), with and without colour and
// a final transform, on boundaries and non-finite points.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "core/base/cpu_dispatch.h"
#include "core/base/random.h"
#include "core/chaos/chaos_game.h"
#include "core/chaos/flame_plot.h"
#include "core/chaos/flame_program.h"
#include "core/chaos/image_plane.h"
#include "tests/support/plot_oracle.h"

namespace nimbus {
namespace {

constexpr int kN = flame::kMaxWalkers;
constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// Walker k's bit of a Plotted mask.
bool Bit(const uint64_t* mask, int k) { return (mask[k / 64] >> (k % 64)) & 1; }

struct Case {
  std::string name;
  ChaosGameParams params;
};

std::vector<Case> Cases() {
  std::vector<Case> cases;
  ChaosGameParams p;
  p.frame = {{100, 70, 40}, {{-1.3, -0.7, -0.5}, {2.1, 1.1, 0.5}}};
  p.color = {ColorMode::kMap, 0.5};
  cases.push_back({"grid_3d", p});
  p.color = {};
  cases.push_back({"grid_3d_no_color", p});
  p.frame = {{1024, 1000, 1}, {{-2, -2, -0.5}, {2, 2, 0.5}}};
  p.color = {ColorMode::kAddress, 0.25};
  cases.push_back({"grid_folded", p});
  p.frame = {{100, 70, 40}, {{-1.3, -0.7, -0.5}, {2.1, 1.1, 0.5}}};
  p.image = MakeImagePlane({}, p.frame.bounds, 640, 333);
  cases.push_back({"ortho", p});
  ImageView camera;
  camera.camera = true;
  camera.position = {3, 2, 4};
  camera.look_at = {0.2, 0.1, 0};
  camera.ortho_height = 2.5;
  p.image = MakeImagePlane(camera, p.frame.bounds, 300, 200);
  cases.push_back({"ortho_camera", p});
  camera.perspective = true;
  camera.fov_degrees = 50;
  p.image = MakeImagePlane(camera, p.frame.bounds, 512, 384);
  cases.push_back({"perspective", p});
  return cases;
}

// A point of the world box grown by a quarter each way, or, one time in
// four, a special value on one axis: the box's edges (voxel coordinate 0 or
// exactly the resolution, and the doubles either side), or non-finite.
double Coordinate(Rng& rng, double lo, double hi) {
  const double pad = 0.25 * (hi - lo);
  if (rng.Uniform() < 0.75) return rng.Uniform(lo - pad, hi + pad);
  const double specials[] = {lo, hi, std::nextafter(lo, -kInf), std::nextafter(hi, -kInf),
                             std::nextafter(lo, kInf), kInf, -kInf, kNaN, 0.0, -0.0};
  return specials[rng.Next() % (sizeof(specials) / sizeof(specials[0]))];
}

void Fill(flame::Walkers& w, const Bounds& b, Rng& rng) {
  for (int k = 0; k < kN; ++k) {
    double* walker[3] = {w.x, w.y, w.z};
    double* plotted[3] = {w.fx, w.fy, w.fz};
    for (int a = 0; a < 3; ++a) {
      walker[a][k] = Coordinate(rng, b.min[a], b.max[a]);
      plotted[a][k] = Coordinate(rng, b.min[a], b.max[a]);
    }
    const double cols[] = {rng.Uniform(-0.2, 1.2), 0.0, 1.0, -0.0, 0.5 / 65535, 1.5 / 65535};
    w.col[k] = cols[rng.Next() % 6];
  }
}

bool Finite(double x, double y, double z) {
  return std::isfinite(x) && std::isfinite(y) && std::isfinite(z);
}

std::vector<SimdLevel> VectorLevels() {
  std::vector<SimdLevel> levels;
  if (DetectSimd() >= SimdLevel::kAvx2) levels.push_back(SimdLevel::kAvx2);
  if (DetectSimd() >= SimdLevel::kAvx512) levels.push_back(SimdLevel::kAvx512);
  return levels;
}

TEST(FlamePlot, ScalarKernelGivesTheEnginesKeys) {
  for (const Case& c : Cases()) {
    SCOPED_TRACE(c.name);
    const CountGrid grid(c.params.CountResolution(), c.params.color.mode != ColorMode::kNone);
    const flame::PlotTarget target = MakePlotTarget(c.params, grid);
    auto w = std::make_unique<flame::Walkers>();
    auto out = std::make_unique<flame::Plotted>();
    Rng rng(3, 0);
    uint64_t inside = 0;
    for (int round = 0; round < 200; ++round) {
      Fill(*w, c.params.frame.bounds, rng);
      const bool final_map = round % 2 == 1;
      flame::PlotScalar(target, *w, final_map, kN, out.get());
      const double* px = final_map ? w->fx : w->x;
      const double* py = final_map ? w->fy : w->y;
      const double* pz = final_map ? w->fz : w->z;
      for (int k = 0; k < kN; ++k) {
        const bool walker = Finite(w->x[k], w->y[k], w->z[k]);
        const bool point = walker && Finite(px[k], py[k], pz[k]);
        EXPECT_EQ(Bit(out->bad_walker, k), !walker) << k;
        EXPECT_EQ(Bit(out->bad_final, k), walker && !point) << k;
        if (!point) {
          EXPECT_FALSE(Bit(out->inside, k)) << k;
          continue;
        }
        const auto want = testing::ExpectedPlotKey(c.params, grid, {px[k], py[k], pz[k]},
                                                   w->col[k]);
        ASSERT_EQ(Bit(out->inside, k), want.has_value())
            << "lane " << k << " at " << px[k] << " " << py[k] << " " << pz[k];
        if (want) {
          EXPECT_EQ(out->key[k], *want) << k;
        }
        inside += want.has_value();
      }
    }
    EXPECT_GT(inside, 1000u);  // the cases do plot
  }
}

TEST(FlamePlot, VectorKernelsGiveTheScalarKernelsKeysBitForBit) {
  if (VectorLevels().empty()) GTEST_SKIP() << "no AVX2 on this CPU";
  for (const Case& c : Cases()) {
    SCOPED_TRACE(c.name);
    const CountGrid grid(c.params.CountResolution(), c.params.color.mode != ColorMode::kNone);
    const flame::PlotTarget target = MakePlotTarget(c.params, grid);
    auto w = std::make_unique<flame::Walkers>();
    auto want = std::make_unique<flame::Plotted>();
    auto got = std::make_unique<flame::Plotted>();
    Rng rng(4, 0);
    for (int round = 0; round < 200; ++round) {
      Fill(*w, c.params.frame.bounds, rng);
      const bool final_map = round % 2 == 0;
      // Whole rounds and partial ones: RunChunkBatch's re-warm block, and
      // a block of chunks that ends inside a mask word.
      const int n = round % 5 == 4 ? 3 * flame::kAlign : round % 5 == 3 ? 88 : kN;
      // A planar program's rounds: z = +0 wherever x and y are finite, and
      // the vector kernels, told so, do not read or test z.
      flame::PlotTarget vector_target = target;
      vector_target.planar = !final_map && round % 4 == 1;
      if (vector_target.planar) {
        for (int k = 0; k < kN; ++k)
          if (std::isfinite(w->x[k]) && std::isfinite(w->y[k])) w->z[k] = 0.0;
      }
      flame::PlotScalar(target, *w, final_map, n, want.get());
      for (SimdLevel level : VectorLevels()) {
        SCOPED_TRACE(std::string(SimdName(level)));
        FlamePlotter(level)(vector_target, *w, final_map, n, got.get());
        for (int i = 0; i < flame::kMaskWords; ++i) {
          ASSERT_EQ(got->inside[i], want->inside[i]) << i;
          ASSERT_EQ(got->bad_walker[i], want->bad_walker[i]) << i;
          ASSERT_EQ(got->bad_final[i], want->bad_final[i]) << i;
        }
        for (int k = n; k < kN; ++k) {
          EXPECT_FALSE(Bit(want->inside, k) || Bit(want->bad_walker, k)) << k;
        }
        for (int k = 0; k < n; ++k) {
          if (Bit(want->inside, k)) {
            EXPECT_EQ(got->key[k], want->key[k]) << k;
          }
        }
      }
    }
  }
}

}  // namespace
}  // namespace nimbus
