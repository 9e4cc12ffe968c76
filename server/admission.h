// Where submitted specs are validated: off the gRPC threads, because
// validation may parse an uploaded mesh or run a pilot census of the
// attractor (tens of milliseconds), and a gRPC thread must only move data.
#pragma once

#include <cstddef>

#include "server/blocking_executor.h"

namespace nimbus::server {

/// @brief One thread running submissions in the order they arrived, with a
/// bounded queue so a flood of submissions is refused rather than buffered.
/// A one-thread BlockingExecutor: one thread keeps admission in order, and
/// a pilot census never competes with another for the cores.
class Admission : public BlockingExecutor {
 public:
  explicit Admission(size_t max_pending = 256) : BlockingExecutor(1, max_pending) {}
};

}  // namespace nimbus::server
