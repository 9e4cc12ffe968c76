#pragma once

// @brief Blosc 1 buffers of byte-shuffled LZ4, the way OpenVDB's writers
// ask libblosc for them, built here so that a leaf's few hundred bytes do
// not pay for clearing a 16 KiB LZ4 table.
//
//   std::string out(n + kBloscOverhead, '\0');
//   out.resize(size_t(BloscLz4(data, n, out.data(), out.size())));
//
// The bytes are those of c-blosc 1.21's
// `blosc_compress_ctx(9, BLOSC_SHUFFLE, 4, n, src, dest, dest_size, "lz4", n, 1)`:
// a 16-byte header (format 2, LZ4 format 1, flags, type size 4, the size,
// the block size and the buffer's size), then either the input as it is
// (flag 0x2, when it is under 128 bytes or does not compress into
// `dest_size`) or the block offsets and the blocks. A block's bytes are
// shuffled (byte k of every 4-byte item together) and, when the block
// holds at least 128 items and is not the short last block, compressed as
// four streams, one per byte plane; each stream is an int32 size and the
// LZ4 bytes at acceleration 1, or the raw bytes when LZ4 saves nothing.
//
// libblosc calls LZ4_compress_fast, which clears the table on every call;
// this calls LZ4's fast-reset entry point on a table kept per thread, which
// gives the same bytes: entries from earlier inputs lie below the current
// input's start and LZ4 rejects them, as a cleared table's never match.
// tests/core/blosc_lz4_test.cc compares the two on many inputs.

#include <cstddef>

namespace nimbus::vdb_native {

/// Blosc's header: the most a buffer grows (BLOSC_MAX_OVERHEAD).
inline constexpr size_t kBloscOverhead = 16;

/// Compresses `n` bytes into `dest` as described above. Requires
/// `dest_size >= n + kBloscOverhead` (then it always fits); returns the
/// buffer's size.
int BloscLz4(const char* src, size_t n, char* dest, size_t dest_size);

}  // namespace nimbus::vdb_native
