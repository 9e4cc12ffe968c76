#include "core/base/heap_tuning.h"

#include <malloc.h>

namespace nimbus {

void KeepFreedHeapForReuse() {
  // Setting either value turns off glibc's adaptive thresholds, so both are
  // set: the mmap one to the adaptive maximum, the trim one above it.
  mallopt(M_MMAP_THRESHOLD, 32 << 20);
  mallopt(M_TRIM_THRESHOLD, 64 << 20);
}

}  // namespace nimbus
