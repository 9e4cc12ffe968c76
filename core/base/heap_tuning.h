// KeepFreedHeapForReuse: a process-wide malloc setting for programs that
// stream large messages.
//
//   int main(int argc, char** argv) {
//     nimbus::KeepFreedHeapForReuse();  // first thing, before any thread
//     ...
//   }
#pragma once

namespace nimbus {

/// @brief Keeps freed heap memory in the process for reuse instead of
/// handing it back to the kernel at once. gRPC reads a download into 64 KiB
/// blocks that are freed as soon as each message is parsed; with glibc's
/// defaults (trim above 128 KiB of free top-of-heap) every 1 MiB chunk grew
/// the heap, touched fresh pages (one fault each) and shrank it again. Up to
/// 64 MiB per arena are now kept, and blocks below 32 MiB come from the heap
/// (the largest size glibc's own adaptive threshold would reach), so large
/// arrays are still mapped and unmapped directly. Meant for a program's
/// main(); a library must not change its host's allocator.
void KeepFreedHeapForReuse();

}  // namespace nimbus
