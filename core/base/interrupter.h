// The single progress-and-cancel hook every long computation in core takes,
// modelled on openvdb::util::NullInterrupter.
#pragma once

#include <cstdint>
#include <string_view>

namespace nimbus {

/// @brief Progress-and-cancel hook. The default implementation never
/// interrupts. Engines call Start/End from the calling thread and
/// WasInterrupted from any of their worker threads, so overrides must be
/// thread-safe and cheap (they are polled every few milliseconds).
class Interrupter {
 public:
  virtual ~Interrupter() = default;
  virtual void Start(std::string_view /*task*/) {}
  virtual void End() {}
  /// @param done units of work finished so far, out of @a total (0 = unknown).
  /// @return true when the computation should stop as soon as possible.
  virtual bool WasInterrupted(uint64_t /*done*/ = 0, uint64_t /*total*/ = 0) { return false; }
};

/// Returns `i` or, when null, a shared never-interrupting instance.
Interrupter& OrNull(Interrupter* i);

}  // namespace nimbus
