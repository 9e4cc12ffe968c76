// The gap filling's pretest kernels (core/sets/gap_pretest.h): every SIMD
// level gives the portable mask, and the portable mask is the definition
// (a neighbour's image two or more voxels away, Chebyshev).
#include "core/sets/gap_pretest.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <bit>
#include <cstdlib>
#include <vector>

#include "core/base/cpu_dispatch.h"
#include "core/base/random.h"

namespace nimbus {
namespace {

uint32_t Pack(int x, int y, int z) {
  auto clamp = [](int v) { return uint32_t(std::clamp(v, 0, 1023)); };
  return clamp(x) | clamp(y) << 10 | clamp(z) << 20;
}

int Chebyshev(uint32_t p, int x, int y, int z) {
  return std::max({std::abs(int(p & 1023u) - x), std::abs(int((p >> 10) & 1023u) - y),
                   std::abs(int(p >> 20) - z)});
}

// A random word and its images, kept alive beside the Word's pointers.
struct Case {
  gap::Word word;
  std::vector<uint32_t> images, images_y, images_z;
};

// Images near their voxels (steps of up to 1, 2 or 5 voxels per axis), so
// that both outcomes of every test occur; bit densities from sparse to full.
Case RandomCase(Rng& rng) {
  Case c;
  gap::Word& g = c.word;
  auto bits = [&] {
    switch (rng.Next() % 4) {
      case 0: return rng.Next() & rng.Next() & rng.Next();
      case 1: return rng.Next();
      case 2: return rng.Next() | rng.Next() | rng.Next();
      default: return ~uint64_t{0};
    }
  };
  g.mov = bits();
  if (!g.mov) g.mov = 1;
  for (uint64_t& s : g.still) s = bits();
  g.moves_x = bits();
  g.moves_y = bits();
  g.moves_z = bits();
  g.x0 = 64 * int(rng.Next() % 16);
  g.y = int(rng.Next() % 1024);
  g.z = int(rng.Next() % 1024);
  static constexpr int kSpread[4] = {1, 1, 2, 5};
  const int spread = kSpread[rng.Next() % 4];
  auto step = [&] { return int(rng.Next() % uint64_t(2 * spread + 1)) - spread; };
  auto near = [&](int x, int y, int z) { return Pack(x + step(), y + step(), z + step()); };
  for (int b = 0; b < 64; ++b)
    if ((g.mov >> b) & 1) c.images.push_back(near(g.x0 + b, g.y, g.z));
  c.images.push_back(near(g.x0 + 64, g.y, g.z));  // the next word's first moving voxel
  for (int b = 0; b < 64; ++b) {
    if ((g.moves_y >> b) & 1) c.images_y.push_back(near(g.x0 + b, g.y + 1, g.z));
    if ((g.moves_z >> b) & 1) c.images_z.push_back(near(g.x0 + b, g.y, g.z + 1));
  }
  g.images = c.images.data();
  g.images_y = c.images_y.empty() ? nullptr : c.images_y.data();
  g.images_z = c.images_z.empty() ? nullptr : c.images_z.data();
  return c;
}

// The definition, voxel by voxel.
uint64_t NeedByDefinition(const gap::Word& g) {
  static constexpr int kStep[6][3] = {{-1, 0, 0}, {1, 0, 0},  {0, -1, 0},
                                      {0, 1, 0},  {0, 0, -1}, {0, 0, 1}};
  uint64_t need = 0;
  for (int b = 0; b < 64; ++b) {
    if (!((g.mov >> b) & 1)) continue;
    const uint64_t below = (uint64_t{1} << b) - 1;
    const int rank = std::popcount(g.mov & below);
    const uint32_t m = g.images[rank];
    const int x = g.x0 + b;
    bool hit = false;
    for (int k = 0; k < 6; ++k)
      if ((g.still[k] >> b) & 1)
        hit |= Chebyshev(m, x + kStep[k][0], g.y + kStep[k][1], g.z + kStep[k][2]) >= 2;
    auto apart = [&](uint32_t q) {
      return Chebyshev(m, int(q & 1023u), int((q >> 10) & 1023u), int(q >> 20)) >= 2;
    };
    if ((g.moves_x >> b) & 1) hit |= apart(g.images[rank + 1]);
    if ((g.moves_y >> b) & 1) hit |= apart(g.images_y[std::popcount(g.moves_y & below)]);
    if ((g.moves_z >> b) & 1) hit |= apart(g.images_z[std::popcount(g.moves_z & below)]);
    if (hit) need |= uint64_t{1} << b;
  }
  return need;
}

TEST(SetMapsGapPretest, PortableMaskIsTheDefinition) {
  Rng rng(11, 0);
  int hits = 0;
  for (int trial = 0; trial < 20000; ++trial) {
    const Case c = RandomCase(rng);
    const uint64_t expected = NeedByDefinition(c.word);
    ASSERT_EQ(gap::NeedPortable(c.word), expected) << "trial " << trial;
    hits += expected != 0 && expected != c.word.mov;
  }
  EXPECT_GT(hits, 5000) << hits;  // mixed outcomes, not all-or-nothing words
}

TEST(SetMapsGapPretest, EveryLevelGivesThePortableMask) {
  std::vector<int> levels;
  if (DetectSimd() >= SimdLevel::kAvx2) levels.push_back(int(SimdLevel::kAvx2));
  if (DetectSimd() >= SimdLevel::kAvx512) levels.push_back(int(SimdLevel::kAvx512));
  if (levels.empty()) GTEST_SKIP() << "no AVX2 on this CPU";
  Rng rng(12, 0);
  for (int trial = 0; trial < 20000; ++trial) {
    const Case c = RandomCase(rng);
    const uint64_t expected = gap::NeedPortable(c.word);
    for (int level : levels)
      ASSERT_EQ(gap::NeedKernel(level)(c.word), expected) << "level " << level << ", trial "
                                                           << trial;
  }
}

TEST(SetMapsGapPretest, KernelChoiceFollowsTheLevel) {
  EXPECT_EQ(gap::NeedKernel(int(SimdLevel::kScalar)), &gap::NeedPortable);
  // Every AVX2 or AVX-512 CPU has BMI2 and POPCNT too.
  if (DetectSimd() >= SimdLevel::kAvx512) {
    EXPECT_EQ(gap::NeedKernel(int(SimdLevel::kAvx512)), &gap::NeedAvx512);
  }
  if (DetectSimd() >= SimdLevel::kAvx2) {
    EXPECT_EQ(gap::NeedKernel(int(SimdLevel::kAvx2)), &gap::NeedAvx2);
  }
}

}  // namespace
}  // namespace nimbus
