#include "core/sets/set_ifs.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <bit>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <vector>

#include "absl/strings/str_cat.h"
#include "core/base/random.h"
#include "core/base/status_macros.h"
#include "core/chaos/point_map.h"
#include "core/sets/shapes.h"

namespace nimbus {
namespace {

using Clock = std::chrono::steady_clock;

double SecondsSince(Clock::time_point t) {
  return std::chrono::duration<double>(Clock::now() - t).count();
}

std::vector<double> Normalised(const SetIfs& ifs) {
  if (ifs.probabilities.empty()) return std::vector<double>(ifs.maps.size(), 1.0 / ifs.maps.size());
  double sum = 0;
  for (double p : ifs.probabilities) sum += p;
  std::vector<double> out;
  for (double p : ifs.probabilities) out.push_back(p / sum);
  return out;
}

std::string Label(const SetIfs& ifs, size_t i) {
  if (!ifs.labels.empty()) return ifs.labels[i];
  if (i < 26) return std::string(1, char('A' + i));
  return absl::StrCat("[", i, "]");
}

// Adds 1 for every member and returns the number of members. Slabs of 32
// slices (one layer of tiles each) first mark the tiles they touch, in
// parallel; the marked tiles are allocated serially; then the slabs count
// into their own tiles in parallel, 32 voxels of a row at a time into one
// tile. The set fills a few percent of the lattice, so both passes work a
// 64-bit word at a time and skip empty words: the marking ORs the 32 x 32
// rows of a tile layer together first and looks at each tile's bits once.
uint64_t AddToCounts(const VoxelSet& set, CountGrid& counts) {
  constexpr int kDim = CountGrid::kTileDim;
  const Int3 r = set.resolution();
  const Int3 tiles = counts.tiles();
  const int words = set.words_per_row();
  const int halves = (r.x + kDim - 1) / kDim;  // 32-voxel halves of row words
  auto tile_of = [&](int tx, int ty, int tz) {
    return (uint64_t(tx) * tiles.y + uint64_t(ty)) * tiles.z + uint64_t(tz);
  };
  std::vector<uint8_t> used(size_t(tiles.x) * tiles.y * tiles.z, 0);
  tbb::parallel_for(tbb::blocked_range<int>(0, tiles.z, 1), [&](const tbb::blocked_range<int>& b) {
    std::vector<uint64_t> any(static_cast<size_t>(words));
    for (int tz = b.begin(); tz < b.end(); ++tz)
      for (int ty = 0; ty * kDim < r.y; ++ty) {
        std::fill(any.begin(), any.end(), 0);
        for (int z = tz * kDim; z < std::min(r.z, (tz + 1) * kDim); ++z)
          for (int y = ty * kDim; y < std::min(r.y, (ty + 1) * kDim); ++y) {
            const uint64_t* row = set.Row(y, z);
            for (int w = 0; w < words; ++w) any[size_t(w)] |= row[w];
          }
        for (int hx = 0; hx < halves; ++hx)
          if (uint32_t(any[size_t(hx >> 1)] >> ((hx & 1) * 32))) used[tile_of(hx, ty, tz)] = 1;
      }
  });
  for (size_t t = 0; t < used.size(); ++t)
    if (used[t]) counts.MutableTile(t);
  std::vector<uint64_t> members(size_t(tiles.z), 0);
  tbb::parallel_for(tbb::blocked_range<int>(0, tiles.z, 1), [&](const tbb::blocked_range<int>& b) {
    for (int tz = b.begin(); tz < b.end(); ++tz) {
      uint64_t n = 0;
      for (int z = tz * kDim; z < std::min(r.z, (tz + 1) * kDim); ++z)
        for (int y = 0; y < r.y; ++y) {
          const uint64_t* row = set.Row(y, z);
          const uint32_t yz = CountGrid::LocalOffset(0, y & (kDim - 1), z & (kDim - 1));
          for (int w = 0; w < words; ++w) {
            if (!row[w]) continue;
            for (int hx = 2 * w; hx < std::min(2 * w + 2, halves); ++hx) {
              uint32_t bits = uint32_t(row[w] >> ((hx & 1) * 32));
              if (!bits) continue;
              uint32_t* tile = counts.MutableTile(tile_of(hx, y / kDim, tz));
              for (; bits; bits &= bits - 1) {
                // LocalOffset is an OR of an x part and a (y, z) part.
                tile[yz | CountGrid::LocalOffset(std::countr_zero(bits), 0, 0)] += 1;
                ++n;
              }
            }
          }
        }
      members[size_t(tz)] = n;
    }
  });
  uint64_t total = 0;
  for (uint64_t n : members) total += n;
  return total;
}

}  // namespace

absl::Status ValidateSetIfs(const SetIfs& ifs) {
  NIMBUS_RETURN_IF_ERROR(ValidateSetFrame(ifs.frame));
  if (ifs.maps.empty()) return absl::InvalidArgumentError("set IFS has no maps");
  for (size_t i = 0; i < ifs.maps.size(); ++i) {
    if (!ifs.maps[i])
      return absl::InvalidArgumentError(absl::StrCat("set IFS map ", i, " is null"));
    const GridFrame& f = ifs.maps[i]->frame();
    if (!(f.resolution == ifs.frame.resolution) || !(f.bounds.min == ifs.frame.bounds.min) ||
        !(f.bounds.max == ifs.frame.bounds.max)) {
      return absl::InvalidArgumentError(
          absl::StrCat("set IFS map ", i, " was built for a different grid frame"));
    }
  }
  if (!ifs.probabilities.empty()) {
    if (ifs.probabilities.size() != ifs.maps.size())
      return absl::InvalidArgumentError("set IFS needs one probability per map");
    double sum = 0;
    for (double p : ifs.probabilities) {
      if (!(p >= 0) || !std::isfinite(p))
        return absl::InvalidArgumentError("set IFS probabilities must be finite and >= 0");
      sum += p;
    }
    if (!(sum > 0)) return absl::InvalidArgumentError("set IFS probabilities sum to zero");
  }
  if (!ifs.labels.empty() && ifs.labels.size() != ifs.maps.size())
    return absl::InvalidArgumentError("set IFS needs one label per map");
  return absl::OkStatus();
}

VoxelSet DefaultStartSet(const GridFrame& frame, uint64_t seed) {
  const Vec3 size = frame.bounds.Size();
  const double radius = std::min({size.x, size.y, size.z}) / 8;
  Rng rng(seed, 0x7374617274ULL);  // "start"
  Vec3 c;
  for (int a = 0; a < 3; ++a)
    c[a] = rng.Uniform(frame.bounds.min[a] + radius, frame.bounds.max[a] - radius);
  absl::StatusOr<VoxelSet> ball = SphereSet(frame, c, radius);
  VoxelSet set = ball.ok() ? *std::move(ball) : VoxelSet(frame.resolution);
  // A frame too coarse for the ball still gets one voxel.
  if (set.Empty()) set.Set(frame.resolution.x / 2, frame.resolution.y / 2, frame.resolution.z / 2);
  return set;
}

absl::StatusOr<SetIfsRunStats> RunSetIfs(const SetIfs& ifs, const SetIfsRunOptions& options,
                                         CountGrid& counts, Interrupter* interrupter) {
  NIMBUS_RETURN_IF_ERROR(ValidateSetIfs(ifs));
  if (!(counts.resolution() == ifs.frame.resolution))
    return absl::InvalidArgumentError("set IFS: count grid resolution differs from the frame");
  if (options.start && !(options.start->resolution() == ifs.frame.resolution))
    return absl::InvalidArgumentError("set IFS: start set resolution differs from the frame");
  const auto t_start = Clock::now();
  Interrupter& intr = OrNull(interrupter);
  intr.Start("set IFS random iteration");
  const AliasTable table(Normalised(ifs));
  Rng rng(options.seed, 0);
  SetMapWorkspace ws;
  ws.interrupter = interrupter;
  VoxelSet current = options.start ? *options.start : DefaultStartSet(ifs.frame, options.seed);
  VoxelSet next(ifs.frame.resolution);
  SetIfsRunStats stats;
  stats.map_uses.assign(ifs.maps.size(), 0);
  const uint64_t total = options.warmup + options.iterations;
  absl::Status status;
  for (uint64_t k = 0; k < total; ++k) {
    if (intr.WasInterrupted(k, total)) {
      status = absl::CancelledError("set IFS interrupted");
      break;
    }
    const uint32_t i = table.Sample(rng.Next());
    ws.seed = HashCoords(options.seed, k, 0x736574ULL);
    status = ifs.maps[i]->Apply(current, next, ws);
    if (!status.ok()) break;
    std::swap(current, next);
    ++stats.map_uses[i];
    ++stats.iterations;
    if (k < options.warmup) continue;
    const auto t0 = Clock::now();
    stats.voxels_counted += AddToCounts(current, counts);  // counting them costs no extra scan
    stats.count_seconds += SecondsSince(t0);
    const uint64_t counted = k + 1 - options.warmup;
    if (options.observer && options.observe_every > 0 && counted % options.observe_every == 0)
      options.observer(counted, counts, current);
  }
  intr.End();
  stats.map_seconds = ws.stats.seconds;
  stats.nearest_seconds = ws.stats.nearest_seconds;
  stats.seconds = SecondsSince(t_start);
  if (!status.ok()) return status;
  return stats;
}

absl::StatusOr<uint64_t> BookPageCount(size_t maps, int depth) {
  if (maps == 0) return absl::InvalidArgumentError("book: no maps");
  if (depth < 0) return absl::InvalidArgumentError("book: depth must be >= 0");
  uint64_t pages = 1;
  for (int d = 0; d < depth; ++d) {
    pages *= maps;
    if (pages > (uint64_t{1} << 20))
      return absl::InvalidArgumentError(
          absl::StrCat("book: ", maps, "^", depth, " pages exceed the limit of 2^20"));
  }
  return pages;
}

absl::Status RunBook(const SetIfs& ifs, const BookOptions& options, const BookPageCallback& on_page,
                     Interrupter* interrupter) {
  NIMBUS_RETURN_IF_ERROR(ValidateSetIfs(ifs));
  NIMBUS_ASSIGN_OR_RETURN(const uint64_t pages, BookPageCount(ifs.maps.size(), options.depth));
  if (options.start && !(options.start->resolution() == ifs.frame.resolution))
    return absl::InvalidArgumentError("book: start set resolution differs from the frame");
  const uint64_t n = ifs.maps.size();
  const int depth = options.depth;
  const uint64_t set_bytes = VoxelSet(ifs.frame.resolution).MemoryBytes();

  // Pages share inner compositions: the page with address w_1..w_k reads
  // the cached set for its last `cached` letters (w_{k-c+1}..w_k, applied
  // first) and applies the remaining outer maps itself. Cache the deepest
  // level that fits in memory (with the level it is built from).
  int cached = 0;
  uint64_t level_size = 1;  // n^cached
  while (cached + 1 < depth && (level_size * n + level_size) * set_bytes <= options.cache_bytes) {
    level_size *= n;
    ++cached;
  }
  uint64_t total_work = pages * uint64_t(depth - cached);
  for (uint64_t j = 1, s = n; j <= uint64_t(cached); ++j, s *= n) total_work += s;
  uint64_t done = 0;

  Interrupter& intr = OrNull(interrupter);
  intr.Start("set IFS book");
  SetMapWorkspace ws;
  ws.interrupter = interrupter;
  // The seed of an application depends only on the suffix it produces, so
  // pages are the same whatever the cache depth.
  auto apply = [&](uint32_t map, uint64_t suffix_len, uint64_t suffix, const VoxelSet& in,
                   VoxelSet& out) -> absl::Status {
    if (intr.WasInterrupted(done, total_work)) return absl::CancelledError("book interrupted");
    ws.seed = HashCoords(options.seed, suffix_len, suffix, 0x626f6f6bULL);
    absl::Status s = ifs.maps[map]->Apply(in, out, ws);
    ++done;
    return s;
  };

  std::vector<VoxelSet> level(
      1, options.start ? *options.start : DefaultStartSet(ifs.frame, options.seed));
  absl::Status status;
  uint64_t prev_size = 1;
  for (int j = 1; j <= cached && status.ok(); ++j) {
    std::vector<VoxelSet> next(prev_size * n);
    for (uint64_t s = 0; s < next.size() && status.ok(); ++s) {
      next[s] = VoxelSet(ifs.frame.resolution);
      // Suffix s = (first letter) * n^(j-1) + (inner suffix).
      status = apply(uint32_t(s / prev_size), j, s, level[s % prev_size], next[s]);
    }
    level = std::move(next);
    prev_size *= n;
  }

  VoxelSet a(ifs.frame.resolution), b(ifs.frame.resolution);
  std::vector<uint32_t> digits(static_cast<size_t>(depth));
  for (uint64_t p = 0; p < pages && status.ok(); ++p) {
    // Address digits, outermost (most significant) first.
    uint64_t rest = p;
    for (int d = depth - 1; d >= 0; --d) {
      digits[size_t(d)] = uint32_t(rest % n);
      rest /= n;
    }
    std::string address;
    for (uint32_t d : digits) address += Label(ifs, d);
    const VoxelSet* current = &level[p % level_size];
    uint64_t suffix_scale = level_size;  // n^(letters already applied)
    for (int d = depth - cached - 1; d >= 0 && status.ok(); --d) {
      VoxelSet& out = current == &a ? b : a;
      const uint64_t len = uint64_t(depth - d);
      suffix_scale *= n;
      status = apply(digits[size_t(d)], len, p % suffix_scale, *current, out);
      current = &out;
    }
    if (status.ok()) status = on_page(p, address, *current);
  }
  intr.End();
  return status;
}

}  // namespace nimbus
