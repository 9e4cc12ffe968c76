// core/io/blosc_lz4.h against libblosc itself: the same call OpenVDB's
// writers make must give the same bytes, for every size class (copied,
// one stream, four byte planes, a short last block, several blocks) and
// for runs of inputs on one thread, which is what leaves the LZ4 table of
// earlier inputs in place.

#include "core/io/blosc_lz4.h"

#include <blosc.h>
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <random>
#include <string>
#include <thread>
#include <vector>

namespace nimbus {
namespace {

using vdb_native::BloscLz4;
using vdb_native::kBloscOverhead;

std::string Library(const std::string& in, size_t room) {
  std::string out(room, '\0');
  const int bytes = blosc_compress_ctx(9, BLOSC_SHUFFLE, 4, in.size(), in.data(), out.data(), room,
                                       BLOSC_LZ4_COMPNAME, in.size(), 1);
  out.resize(bytes > 0 ? size_t(bytes) : 0);
  return out;
}

std::string Ours(const std::string& in, size_t room) {
  std::string out(room, '\0');
  const int bytes = BloscLz4(in.data(), in.size(), out.data(), room);
  out.resize(bytes > 0 ? size_t(bytes) : 0);
  return out;
}

// Inputs like a leaf's values: counts as floats, their halves, zeros,
// noise, a repeating pattern and sparse spikes.
std::string Input(int kind, size_t n, std::mt19937& rng) {
  std::string s(n, '\0');
  auto put = [&](size_t at, const void* v, size_t bytes) {
    if (at < n) std::memcpy(s.data() + at, v, std::min(bytes, n - at));
  };
  for (size_t i = 0; i < n; i += 4) {
    const uint32_t r = rng();
    switch (kind) {
      case 0: {  // small counts as floats
        const float f = float(r % 7 == 0 ? r % 40 : 1 + r % 3);
        put(i, &f, 4);
        break;
      }
      case 1: {  // a smooth ramp as halves (two per item)
        const uint16_t h[2] = {uint16_t(0x3c00 + (i / 4) % 97), uint16_t(0x3c00 + (i / 4) % 89)};
        put(i, h, 4);
        break;
      }
      case 2:  // zeros
        break;
      case 3:  // noise
        put(i, &r, 4);
        break;
      case 4: {  // a short repeating pattern
        const uint32_t p = 0x01020304u * uint32_t(1 + (i / 4) % 5);
        put(i, &p, 4);
        break;
      }
      default: {  // sparse spikes in zeros
        const float f = r % 61 == 0 ? std::ldexp(float(r % 1000), -3) : 0.0f;
        put(i, &f, 4);
        break;
      }
    }
  }
  return s;
}

void ExpectSame(const std::string& in, size_t room, const std::string& what) {
  const std::string want = Library(in, room), got = Ours(in, room);
  ASSERT_FALSE(want.empty()) << what;
  ASSERT_EQ(got.size(), want.size()) << what;
  ASSERT_TRUE(got == want) << what;
}

TEST(BloscLz4, EverySmallSizeMatchesLibblosc) {
  std::mt19937 rng(7);
  for (size_t n = 0; n <= 1100; ++n)
    for (int kind = 0; kind < 6; ++kind)
      ExpectSame(Input(kind, n, rng), n + kBloscOverhead,
                 "n=" + std::to_string(n) + " kind=" + std::to_string(kind));
}

TEST(BloscLz4, LargerAndSeveralBlocksMatchLibblosc) {
  std::mt19937 rng(11);
  const size_t sizes[] = {1536,  2048,  4095,  4096,   4097,   6144,    16382,           65535,
                          65536, 65539, 70001, 262144, 300002, 1048576, 1048576 * 2 + 6, 3000001};
  for (size_t n : sizes)
    for (int kind = 0; kind < 6; ++kind)
      for (size_t extra : {size_t(0), size_t(1000)})
        ExpectSame(Input(kind, n, rng), n + kBloscOverhead + extra,
                   "n=" + std::to_string(n) + " kind=" + std::to_string(kind));
}

// The padded and the leaf-sized inputs of a real write, in a random order
// on each of two threads: each thread's table carries over from input to
// input, through its offsets' wrap and the clears of inputs from 4 KiB.
TEST(BloscLz4, RunsOfInputsOnSeveralThreadsMatchLibblosc) {
  auto run = [](unsigned seed, int* mismatches) {
    std::mt19937 rng(seed);
    for (int i = 0; i < 4000; ++i) {
      const size_t n = rng() % 8 == 0 ? 4096 + rng() % 3000 : rng() % 2100;
      const std::string in = Input(int(rng() % 6), n, rng);
      const size_t room = n + kBloscOverhead;
      if (Library(in, room) != Ours(in, room)) ++*mismatches;
    }
  };
  int a = 0, b = 0;
  std::thread t1(run, 1u, &a), t2(run, 2u, &b);
  t1.join();
  t2.join();
  EXPECT_EQ(a, 0);
  EXPECT_EQ(b, 0);
}

TEST(BloscLz4, CopiesWhatDoesNotCompressAndRefusesTooSmallABuffer) {
  std::mt19937 rng(3);
  const std::string noise = Input(3, 1000, rng);
  const std::string out = Ours(noise, noise.size() + kBloscOverhead);
  ASSERT_EQ(out.size(), noise.size() + kBloscOverhead);
  EXPECT_EQ(out[2] & 0x2, 0x2);  // BLOSC_MEMCPYED
  EXPECT_EQ(out.substr(kBloscOverhead), noise);
  std::string small(noise.size(), '\0');
  EXPECT_EQ(BloscLz4(noise.data(), noise.size(), small.data(), small.size()), 0);
  EXPECT_EQ(BloscLz4(noise.data(), noise.size(), small.data(), 8), 0);
}

}  // namespace
}  // namespace nimbus
