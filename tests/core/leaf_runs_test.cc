// LeafRuns keeps encoded leaves in kernel-mapped blocks and spills past a
// bound; ZeroPages maps huge ranges in whole huge pages. Both exist to
// avoid 4 KiB page faults, so the tests pin what must not change with
// them: the bytes written back, and the sizes mapped.
#include "core/io/leaf_runs.h"

#include <gtest/gtest.h>
#include <sys/mman.h>
#include <unistd.h>

#include <cstdint>
#include <cstring>
#include <filesystem>
#include <sstream>
#include <string>
#include <vector>

#include "core/base/zero_pages.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

using vdb_internal::LeafRuns;
using vdb_internal::SpillScope;

// Runs of awkward sizes (a byte, a page and a bit, a whole block and more)
// whose bytes say where they came from.
std::vector<std::string> Runs() {
  std::vector<std::string> runs;
  const size_t sizes[] = {
      1, 4097,  100'000, (size_t{256} << 10) - 7, 3, size_t{4} << 20, (size_t{1} << 20) + 11,
      0, 65'536};
  uint32_t x = 12345;
  for (size_t n : sizes) {
    std::string r(n, '\0');
    for (char& c : r) c = char((x = x * 1664525u + 1013904223u) >> 24);
    runs.push_back(std::move(r));
  }
  return runs;
}

std::string Concatenated(const std::vector<std::string>& runs) {
  std::string all;
  for (const std::string& r : runs) all += r;
  return all;
}

std::string Written(const LeafRuns& runs) {
  std::ostringstream os(std::ios::binary);
  runs.WriteTo(os);
  return os.str();
}

TEST(LeafRuns, KeptRunsWriteBackInOrderAcrossBlocks) {
  const std::vector<std::string> runs = Runs();
  LeafRuns kept;  // no SpillScope: everything stays in memory
  for (const std::string& r : runs) kept.Append(r);
  const std::string all = Concatenated(runs);
  EXPECT_FALSE(kept.spilled());
  EXPECT_EQ(kept.bytes(), all.size());
  EXPECT_TRUE(Written(kept) == all);  // not EXPECT_EQ: a mismatch would print megabytes
}

TEST(LeafRuns, SpilledRunsFollowTheKeptOnes) {
  const std::vector<std::string> runs = Runs();
  const testing::TempDir tmp;
  const std::filesystem::path dir = tmp.path();
  {
    // Keeps the first three runs (one block and part of the next), then
    // spills the rest, a large one included.
    SpillScope spill(dir, runs[0].size() + runs[1].size() + runs[2].size());
    LeafRuns mixed;
    for (const std::string& r : runs) mixed.Append(r);
    EXPECT_TRUE(mixed.spilled());
    EXPECT_TRUE(Written(mixed) == Concatenated(runs));
    // Moving keeps the blocks and the spill file.
    LeafRuns moved(std::move(mixed));
    EXPECT_TRUE(Written(moved) == Concatenated(runs));
  }
  // The spill file was unnamed: nothing is left in the folder.
  EXPECT_TRUE(std::filesystem::is_empty(dir));
}

TEST(ZeroPages, HugeMappingsFromHalfAHugePageEndOnOne) {
  constexpr size_t kHuge = ZeroPages::kHugePage;
  // Small huge requests keep 4 KiB pages rather than more than double.
  EXPECT_EQ(ZeroPages::MappedBytes(512 << 10, true), size_t{512} << 10);
  EXPECT_EQ(ZeroPages::MappedBytes(kHuge / 2, true), kHuge);
  EXPECT_EQ(ZeroPages::MappedBytes(kHuge + 1, true), 2 * kHuge);
  EXPECT_EQ(ZeroPages::MappedBytes(kHuge + 1, false), kHuge + 4096);
  const ZeroPages p(1'300'000, /*huge=*/true);
  EXPECT_EQ(p.bytes(), kHuge);
  EXPECT_EQ(reinterpret_cast<uintptr_t>(p.as<char>()) % kHuge, 0u);
  // The whole mapping is usable and zero.
  const char* c = p.as<char>();
  EXPECT_EQ(c[0], 0);
  EXPECT_EQ(c[p.bytes() - 1], 0);
}

// Pages of [p, p + bytes) the process has mapped (mincore).
size_t ResidentPages(const void* p, size_t bytes) {
  const size_t page = size_t(sysconf(_SC_PAGESIZE));
  std::vector<unsigned char> in((bytes + page - 1) / page);
  if (mincore(const_cast<void*>(p), bytes, in.data()) != 0) return 0;
  size_t n = 0;
  for (unsigned char b : in) n += b & 1;
  return n;
}

TEST(ZeroPages, PopulatedMappingsAreMappedZeroAndUsable) {
  const size_t bytes = 300'000, page = size_t(sysconf(_SC_PAGESIZE));
  void* p = ZeroPages::MapPopulated(bytes);
  const size_t pages = (bytes + page - 1) / page;
  // Kernels before 5.14 refuse the advice; the pages then fault in as usual.
  if (const size_t resident = ResidentPages(p, bytes); resident != 0) {
    EXPECT_EQ(resident, pages);
  }
  const auto* c = static_cast<const unsigned char*>(p);
  for (size_t i = 0; i < bytes; i += 997) ASSERT_EQ(c[i], 0);
  std::memset(p, 7, bytes);
  EXPECT_EQ(c[bytes - 1], 7);
  ZeroPages::Unmap(p, bytes, /*huge=*/false);
  // Mid-size allocator buffers come populated and keep what is written.
  std::vector<uint32_t, ZeroPageAllocator<uint32_t>> v(100'000);
  for (uint32_t i = 0; i < v.size(); ++i) v[i] = i * 3;
  uint64_t sum = 0;
  for (uint32_t x : v) sum += x;
  EXPECT_EQ(sum, 3ull * (99'999ull * 100'000 / 2));
}

TEST(ZeroPages, AllocatorVectorsOfOddSizesRoundTrip) {
  // 1.3 MB of 80-byte elements, as a 2D picture's leaf list: mapped in a
  // whole huge page, unmapped with the same size.
  struct Item {
    uint64_t v[10];
  };
  for (int round = 0; round < 3; ++round) {
    std::vector<Item, ZeroPageAllocator<Item>> items;
    items.reserve(16384);
    for (uint64_t i = 0; i < 16384; ++i) items.push_back(Item{{i, i * 3}});
    EXPECT_EQ(reinterpret_cast<uintptr_t>(items.data()) % ZeroPages::kHugePage, 0u);
    uint64_t sum = 0;
    for (const Item& it : items) sum += it.v[1];
    EXPECT_EQ(sum, 3 * (16383ull * 16384 / 2));
  }
}

}  // namespace
}  // namespace nimbus
