// Partial results of a sharded chaos game (docs/sharding.md): one shard's
// counts, colour sums and counters in a file, and their exact sum.
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>
#include <string_view>

#include "absl/status/status.h"
#include "core/chaos/chaos_game.h"
#include "core/grid/count_grid.h"

namespace nimbus {

/// @brief Writes `counts` and `stats` to `path` as a chaos partial: a
/// header (magic "NIMBUSCP", format version, resolution, colour flag, the
/// four counters), then each allocated tile with any visit as its index and
/// its 32^3 counters (and colour sums), then the SHA-256 (hex) of all that.
/// Integers are little-endian. All-zero tiles are left out: the VDB writer
/// skips empty leaves, so they change no output.
absl::Status SaveChaosPartial(const std::filesystem::path& path, const CountGrid& counts,
                              const ChaosGameStats& stats);

/// @brief Adds the partial in `bytes` to `counts` (same resolution and
/// colour flag) and its counters to `stats`. Integer sums, saturating as
/// CountGrid::Merge does, so partials added in any order give the counts
/// of the whole run. DATA_LOSS for a damaged partial, INVALID_ARGUMENT for
/// one of another grid.
absl::Status AddChaosPartial(std::string_view bytes, CountGrid& counts, ChaosGameStats& stats);

/// Reads the file at `path` and adds it as AddChaosPartial does.
absl::Status AddChaosPartialFile(const std::filesystem::path& path, CountGrid& counts,
                                 ChaosGameStats& stats);

}  // namespace nimbus
