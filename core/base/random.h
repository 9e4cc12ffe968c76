// Reproducible random streams. A stream is a pure function of (seed, stream
// id), so work split into numbered chunks gives the same numbers whatever
// thread runs each chunk.
#pragma once

#include <cstdint>

namespace nimbus {

/// SplitMix64 finaliser: a bijective 64-bit mixer, also used as a hash.
constexpr uint64_t Mix64(uint64_t z) {
  z += 0x9e3779b97f4a7c15ULL;
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
  return z ^ (z >> 31);
}

/// Hash of integer coordinates and a seed, for lattice noise (the node values
/// of fractal fields, core/field/node_hash.h).
constexpr uint64_t HashCoords(uint64_t seed, uint64_t a, uint64_t b = 0, uint64_t c = 0,
                              uint64_t d = 0, uint64_t e = 0) {
  uint64_t h = Mix64(seed);
  h = Mix64(h ^ a);
  h = Mix64(h ^ b);
  h = Mix64(h ^ c);
  h = Mix64(h ^ d);
  return Mix64(h ^ e);
}

/// @brief xoshiro256++ generator, seeded per stream through SplitMix64.
class Rng {
 public:
  Rng() : Rng(0, 0) {}
  Rng(uint64_t seed, uint64_t stream) {
    uint64_t z = Mix64(seed) ^ Mix64(stream * 0xd1342543de82ef95ULL + 0x632be59bd9b4e019ULL);
    for (auto& w : s_) {
      z += 0x9e3779b97f4a7c15ULL;
      w = Mix64(z);
    }
  }
  uint64_t Next() {
    const uint64_t result = Rotl(s_[0] + s_[3], 23) + s_[0];
    const uint64_t t = s_[1] << 17;
    s_[2] ^= s_[0];
    s_[3] ^= s_[1];
    s_[1] ^= s_[2];
    s_[0] ^= s_[3];
    s_[2] ^= t;
    s_[3] = Rotl(s_[3], 45);
    return result;
  }
  /// Uniform in [0, 1) with 53 random bits.
  double Uniform() { return (Next() >> 11) * 0x1.0p-53; }
  /// Uniform in [a, b).
  double Uniform(double a, double b) { return a + (b - a) * Uniform(); }

  /// The four state words, for kernels that keep generators in their own
  /// layout (core/affine_walk.h) and hand them back.
  uint64_t state(int i) const { return s_[i]; }
  static Rng FromState(uint64_t s0, uint64_t s1, uint64_t s2, uint64_t s3) {
    Rng r;
    r.s_[0] = s0, r.s_[1] = s1, r.s_[2] = s2, r.s_[3] = s3;
    return r;
  }

 private:
  static constexpr uint64_t Rotl(uint64_t x, int k) { return (x << k) | (x >> (64 - k)); }
  uint64_t s_[4];
};

}  // namespace nimbus
