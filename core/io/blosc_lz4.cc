#include "core/io/blosc_lz4.h"

#define LZ4_STATIC_LINKING_ONLY  // LZ4_compress_fast_extState_fastReset
#include <emmintrin.h>
#include <lz4.h>

#include <algorithm>
#include <climits>
#include <cstdint>
#include <cstring>
#include <vector>

namespace nimbus::vdb_native {

namespace {

constexpr int32_t kTypeSize = 4;
// Blosc's MIN_BUFFERSIZE: smaller inputs are copied, and a block is split
// into byte planes only from this many items on.
constexpr int32_t kMinBuffer = 128;
constexpr int32_t kMaxBlock = int32_t((INT_MAX - 255 * sizeof(int32_t)) / 3);
constexpr uint8_t kShuffleFlag = 0x1, kCopiedFlag = 0x2, kDontSplitFlag = 0x10;
constexpr uint8_t kLz4Format = 1 << 5;

bool Splits(int32_t block) { return block / kTypeSize >= kMinBuffer; }

// compute_blocksize for a block size forced to the whole input, level 9.
int32_t BlockSize(int32_t n) {
  if (n < kTypeSize) return 1;
  int32_t block = std::clamp(n, kMinBuffer, kMaxBlock);
  if (Splits(block)) block = std::clamp(std::min(block, 1 << 18) * kTypeSize, 1 << 16, 1 << 20);
  block = std::min(block, n);
  if (block > kTypeSize) block = block / kTypeSize * kTypeSize;
  return block;
}

void Put32(char* at, int32_t v) { std::memcpy(at, &v, sizeof(v)); }

// One LZ4 table per thread, cleared once (LZ4's fast reset keeps it valid).
struct Lz4Table {
  Lz4Table() { LZ4_initStream(&stream, sizeof(stream)); }
  LZ4_stream_t stream;
};

struct Output {
  char* dest;
  int32_t size;   // bytes written so far (blosc's ntbytes)
  int32_t limit;  // dest_size (blosc's maxbytes)
};

// blosc_c: one block, already shuffled; false when it does not fit.
bool CompressBlock(const uint8_t* shuffled, int32_t bytes, int splits, Output& out) {
  static thread_local Lz4Table table;
  const int32_t stream = bytes / splits;
  for (int s = 0; s < splits; ++s) {
    const char* in = reinterpret_cast<const char*>(shuffled) + s * stream;
    char* size_at = out.dest + out.size;
    out.size += int32_t(sizeof(int32_t));
    int32_t room = stream;
    if (out.size + room > out.limit) room = out.limit - out.size;
    if (room <= 0) return false;
    int32_t packed = LZ4_compress_fast_extState_fastReset(&table.stream, in, out.dest + out.size,
                                                          stream, room, 1);
    if (packed == 0 || packed == stream) {
      if (out.size + stream > out.limit) return false;
      std::memcpy(out.dest + out.size, in, size_t(stream));
      packed = stream;
    }
    Put32(size_at, packed);
    out.size += packed;
  }
  return true;
}

// Byte k of item i to k * items + i; a tail of under 4 bytes stays.
// Sixteen items at a time by three rounds of byte unpacking (SSE2, the
// x86-64 baseline): a round interleaves items i and i + 4 (then i + 2,
// then i + 1), which leaves each byte plane's sixteen bytes in two halves.
void Shuffle(const uint8_t* src, int32_t bytes, uint8_t* dest) {
  const int32_t items = bytes / kTypeSize;
  int32_t i = 0;
  for (; i + 16 <= items; i += 16) {
    const uint8_t* in = src + i * kTypeSize;
    __m128i a[4], b[4];
    for (int k = 0; k < 4; ++k)
      a[k] = _mm_loadu_si128(reinterpret_cast<const __m128i*>(in + 16 * k));
    for (int round = 0; round < 3; ++round) {
      b[0] = _mm_unpacklo_epi8(a[0], a[1]), b[1] = _mm_unpackhi_epi8(a[0], a[1]);
      b[2] = _mm_unpacklo_epi8(a[2], a[3]), b[3] = _mm_unpackhi_epi8(a[2], a[3]);
      std::copy(b, b + 4, a);
    }
    const __m128i planes[4] = {_mm_unpacklo_epi64(a[0], a[2]), _mm_unpackhi_epi64(a[0], a[2]),
                               _mm_unpacklo_epi64(a[1], a[3]), _mm_unpackhi_epi64(a[1], a[3])};
    for (int k = 0; k < 4; ++k)
      _mm_storeu_si128(reinterpret_cast<__m128i*>(dest + k * items + i), planes[k]);
  }
  for (; i < items; ++i)
    for (int32_t k = 0; k < kTypeSize; ++k) dest[k * items + i] = src[i * kTypeSize + k];
  std::memcpy(dest + items * kTypeSize, src + items * kTypeSize, size_t(bytes % kTypeSize));
}

// serial_blosc: the block offsets and the blocks; false when they do not fit.
bool CompressBlocks(const uint8_t* src, int32_t n, int32_t block, bool split, Output& out) {
  static thread_local std::vector<uint8_t> shuffled;
  const int32_t blocks = n / block + (n % block > 0);
  char* starts = out.dest + kBloscOverhead;
  out.size = int32_t(kBloscOverhead) + blocks * int32_t(sizeof(int32_t));
  if (out.size > out.limit) return false;
  shuffled.resize(size_t(block));
  for (int32_t j = 0; j < blocks; ++j) {
    Put32(starts + j * sizeof(int32_t), out.size);
    const bool last_short = j == blocks - 1 && n % block > 0;
    const int32_t bytes = last_short ? n % block : block;
    Shuffle(src + int64_t(j) * block, bytes, shuffled.data());
    if (!CompressBlock(shuffled.data(), bytes, split && !last_short ? kTypeSize : 1, out))
      return false;
  }
  return true;
}

}  // namespace

int BloscLz4(const char* src, size_t n_bytes, char* dest, size_t dest_size) {
  if (n_bytes > size_t(INT_MAX) - kBloscOverhead || dest_size < kBloscOverhead) return 0;
  const int32_t n = int32_t(n_bytes);
  const int32_t block = BlockSize(n);
  Output out{dest, 0, int32_t(std::min(dest_size, size_t(INT_MAX)))};
  const bool split = Splits(block);
  uint8_t flags = kShuffleFlag | (split ? 0 : kDontSplitFlag) | kLz4Format;
  const bool compressed = n >= kMinBuffer && CompressBlocks(reinterpret_cast<const uint8_t*>(src),
                                                            n, block, split, out);
  if (!compressed) {
    if (n + int32_t(kBloscOverhead) > out.limit) return 0;
    flags |= kCopiedFlag;
    std::memcpy(dest + kBloscOverhead, src, size_t(n));
    out.size = n + int32_t(kBloscOverhead);
  }
  dest[0] = 2, dest[1] = 1, dest[2] = char(flags), dest[3] = char(kTypeSize);
  Put32(dest + 4, n);
  Put32(dest + 8, block);
  Put32(dest + 12, out.size);
  return out.size;
}

}  // namespace nimbus::vdb_native
