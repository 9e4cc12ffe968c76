// The portable flame kernel, one lane at a time with the C library's
// functions: the scalar reference the SIMD kernels are tested against, and
// bitwise what PointMap::ApplyWords computes.
#include "core/chaos/flame_walk.h"

#include "core/chaos/flame_walk_kernel.h"

namespace nimbus::flame {
namespace {

struct ScalarIsa {
  using T = double;
  static constexpr int kWidth = 1;
  static constexpr bool kStaged = false;
  static double Load(const double* p) { return *p; }
  static void Store(double* p, double v) { *p = v; }
  static int32_t Index(const int32_t* lanes) { return lanes[0]; }
  static double ToDouble(int32_t i) { return double(i); }
  static void PickMaps(const Program& p, Walkers& w, int n) { PickMapsScalar(p, w, n); }
  static void SortByMap(uint32_t maps, Walkers& w, int n) { SortByMapScalar(maps, w, n); }
  static double Gather(const double* base, int32_t i) { return base[i]; }
  static double LookupMaps(const double* table, uint32_t, int32_t i) { return table[i]; }
  static void Scatter(double* base, int32_t i, double v) { base[i] = v; }
  static uint64_t GatherWord(const uint64_t* base, int32_t i) { return base[i]; }
  static uint64_t LoadWord(const uint64_t* p) { return *p; }
  static double Uniform(uint64_t w) { return double(w >> 11) * 0x1.0p-53; }
  static bool Bit(uint64_t w) { return (w >> 63) != 0; }
  static double Zero() { return 0.0; }
  static uint64_t Rotl(uint64_t x, int k) { return (x << k) | (x >> (64 - k)); }
  // Rng::Next, walker by walker.
  static void DrawWords(Walkers& w, int n, uint32_t words) {
    for (int k = 0; k < n; ++k) {
      uint64_t s0 = w.s0[k], s1 = w.s1[k], s2 = w.s2[k], s3 = w.s3[k];
      for (uint32_t c = 0; c < words; ++c) {
        w.words[size_t(c) * kMaxWalkers + k] = Rotl(s0 + s3, 23) + s0;
        const uint64_t t = s1 << 17;
        s2 ^= s0, s3 ^= s1, s1 ^= s2, s0 ^= s3, s2 ^= t;
        s3 = Rotl(s3, 45);
      }
      w.s0[k] = s0, w.s1[k] = s1, w.s2[k] = s2, w.s3[k] = s3;
    }
  }
};

}  // namespace

void RoundScalar(const Program& p, Walkers& w, int n) { RoundWith<ScalarIsa>(p, w, n); }

}  // namespace nimbus::flame
