// The shape of a submitted spec, checked before any field is read: its
// serialised size, fields this build does not know, and how many entries
// each repeated field holds. A spec that passes is small enough to copy,
// store and send back with every GetJob.
//
//   if (absl::Status st = spec::CheckSpecShape(req.spec(), limits); !st.ok())
//     return st;  // e.g. "image.palette.stops: must have at most 4096 entries, got 1000000"
#pragma once

#include <cstddef>

#include "absl/status/status.h"
#include "nimbus/v1/spec.pb.h"
#include "proto/spec_convert.h"

namespace nimbus::spec {

/// Largest serialised spec: far above any real one (a 4096-map IFS is
/// about 0.5 MB), far below what would make storing or listing jobs costly.
inline constexpr size_t kMaxSpecBytes = size_t{4} << 20;
/// Most entries of any repeated field not bounded more tightly by name.
inline constexpr int kMaxRepeatedEntries = 65'536;
/// Most stops of a palette.
inline constexpr int kMaxPaletteStops = 4096;

/// INVALID_ARGUMENT naming the field for: a spec over kMaxSpecBytes; any
/// field this build does not know (a newer client's, or garbage), which
/// would otherwise be stored and returned unread; a repeated field with
/// more entries than its bound (palette stops kMaxPaletteStops, maps
/// limits.max_maps when larger than the default, others
/// kMaxRepeatedEntries). Makes no copy of the spec.
absl::Status CheckSpecShape(const v1::JobSpec& spec, const Limits& limits);

}  // namespace nimbus::spec
