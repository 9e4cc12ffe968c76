// Spec bytes -> ParseSpec (JSON and text format) -> ConvertSpec, as a
// network server would see them: no local paths, no asset directory, and
// small structural limits so a valid spec never allocates much.
#include "proto/spec_convert.h"
#include "proto/spec_io.h"
#include "tests/fuzz/fuzz_util.h"

namespace {

nimbus::spec::Limits SmallLimits() {
  nimbus::spec::Limits limits;
  limits.max_resolution = 64;
  limits.max_voxels = 64 * 64 * 64;
  limits.max_memory_bytes = uint64_t{64} << 20;
  // Iteration counts are only compared here, never allocated for, so the
  // examples' counts may pass.
  limits.max_iterations = uint64_t{1} << 40;
  limits.max_maps = 64;
  limits.allow_local_paths = false;
  return limits;
}

void ParseAndConvert(const std::string& text, nimbus::spec::SpecFormat format) {
  static const nimbus::spec::Limits limits = SmallLimits();
  auto spec = nimbus::spec::ParseSpec(text, format, "fuzz");
  if (!spec.ok()) return;
  (void)nimbus::spec::ConvertSpec(*spec, limits);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text(nimbus::fuzz::AsView(data, size));
  // Both parsers on every input: the mutator then need not find the
  // leading '{' that kAuto would use to choose.
  ParseAndConvert(text, nimbus::spec::SpecFormat::kJson);
  ParseAndConvert(text, nimbus::spec::SpecFormat::kText);
  return 0;
}
