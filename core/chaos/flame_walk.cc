// The portable flame kernel, one lane at a time with the C library's
// functions: the scalar reference the SIMD kernels are tested against, and
// bitwise what PointMap::Apply computes.
#include "core/chaos/flame_walk.h"

#include "core/chaos/flame_walk_kernel.h"

namespace nimbus::flame {
namespace {

struct ScalarIsa {
  using T = double;
  static constexpr int kWidth = 1;
  static double Load(const double* p) { return *p; }
  static void Store(double* p, double v) { *p = v; }
  static int64_t Index(const int64_t* map) { return 12 * map[0]; }
  static double Gather(const double* table, int64_t index, int j) { return table[index + j]; }
  static double Zero() { return 0.0; }
  static bool MapIs(const int64_t* map, uint32_t m) { return map[0] == int64_t(m); }
  static bool Any(bool b) { return b; }
};

}  // namespace

void ApplyMapsScalar(const MapTables& t, Batch& b) { ApplyMapsWith<ScalarIsa>(t, b); }

}  // namespace nimbus::flame
