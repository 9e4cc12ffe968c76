#include "core/jelly/jelly_render.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <numeric>
#include <unordered_map>

#include "core/base/random.h"

namespace nimbus {

namespace {

// Leaves per interrupter poll: ~64k affine maps is well under 10 ms.
constexpr uint64_t kPollLeaves = uint64_t{1} << 16;
// Chaos-game points per random stream, and unplotted steps per stream.
constexpr uint64_t kChaosChunk = 4096;
constexpr int kChaosWarmup = 24;

// Runs body(begin, end) over [0, n) in fixed chunks, polling between
// chunks; CANCELLED when interrupted.
template <typename F>
absl::Status ForChunks(uint64_t n, uint64_t chunk, Interrupter* interrupter, F&& body) {
  std::atomic<bool> stop{false};
  const uint64_t chunks = (n + chunk - 1) / chunk;
  tbb::parallel_for(tbb::blocked_range<uint64_t>(0, chunks, 1),
                    [&](const tbb::blocked_range<uint64_t>& r) {
                      for (uint64_t c = r.begin(); c != r.end(); ++c) {
                        if (stop.load(std::memory_order_relaxed)) return;
                        if (OrNull(interrupter).WasInterrupted(c * chunk, n)) {
                          stop = true;
                          return;
                        }
                        body(c, c * chunk, std::min(n, (c + 1) * chunk));
                      }
                    });
  return stop ? absl::CancelledError("interrupted") : absl::OkStatus();
}

absl::Status VrrLeaves(const std::vector<Affine3>& maps, const JellyRender& render,
                       std::vector<Vec3>& out, Interrupter* interrupter) {
  // Level k+1 = M_0(level k) ++ M_1(level k) ++ …: the first map of a word
  // is applied last, so it is the most significant digit of the index.
  std::vector<Vec3> level = render.start_points, next;
  const uint64_t n_maps = maps.size();
  for (uint32_t d = 0; d < render.depth; ++d) {
    const uint64_t prev = level.size();
    next.resize(prev * n_maps);
    absl::Status st = ForChunks(next.size(), kPollLeaves, interrupter,
                                [&](uint64_t, uint64_t begin, uint64_t end) {
                                  for (uint64_t k = begin; k < end; ++k)
                                    next[k] = maps[k / prev].Apply(level[k % prev]);
                                });
    if (!st.ok()) return st;
    level.swap(next);
  }
  out = std::move(level);
  return absl::OkStatus();
}

absl::Status ChaosLeaves(const std::vector<Affine3>& maps, const JellyRender& render,
                         std::vector<Vec3>& out, Interrupter* interrupter) {
  std::vector<double> cumulative(maps.size());
  for (size_t i = 0; i < maps.size(); ++i)
    cumulative[i] = (i ? cumulative[i - 1] : 0) + (render.weights.empty() ? 1 : render.weights[i]);
  const double total = cumulative.back();
  const Vec3 start = render.start_points.empty() ? Vec3{} : render.start_points[0];
  out.resize(render.points);
  auto pick = [&](Rng& rng) {
    const double u = rng.Uniform() * total;
    size_t i = 0;
    while (i + 1 < cumulative.size() && u >= cumulative[i]) ++i;
    return i;
  };
  return ForChunks(render.points, kChaosChunk, interrupter,
                   [&](uint64_t chunk, uint64_t begin, uint64_t end) {
                     Rng rng(render.seed, chunk);
                     Vec3 p = start;
                     for (int w = 0; w < kChaosWarmup; ++w) p = maps[pick(rng)].Apply(p);
                     for (uint64_t k = begin; k < end; ++k) out[k] = p = maps[pick(rng)].Apply(p);
                   });
}

}  // namespace

uint64_t VrrLeafCount(uint64_t maps, uint32_t depth, uint64_t start_points) {
  uint64_t n = start_points;
  for (uint32_t d = 0; d < depth; ++d) {
    if (maps != 0 && n > std::numeric_limits<uint64_t>::max() / maps)
      return std::numeric_limits<uint64_t>::max();
    n *= maps;
  }
  return n;
}

absl::Status JellyLeaves(const std::vector<Affine3>& maps, const JellyRender& render,
                         std::vector<Vec3>& out, Interrupter* interrupter) {
  if (maps.empty()) return absl::InvalidArgumentError("no maps");
  return render.mode == JellyRenderMode::kVrr ? VrrLeaves(maps, render, out, interrupter)
                                               : ChaosLeaves(maps, render, out, interrupter);
}

uint64_t ClampToGround(std::vector<Vec3>& leaves, double height) {
  uint64_t moved = 0;
  for (Vec3& p : leaves)
    if (p.y < height) p.y = height, ++moved;
  return moved;
}

absl::StatusOr<JellyFrameGrids> AccumulateLeaves(const std::vector<Vec3>& leaves,
                                                 const std::vector<Vec3>& prev, double seconds,
                                                 const GridFrame& frame, bool velocity,
                                                 Interrupter* interrupter) {
  JellyFrameGrids g{CountGrid(frame.resolution), Vec3Field{"v", {}}, 0};
  const Int3 r = frame.resolution;
  const Vec3 h = frame.VoxelSize();
  const bool have_prev = prev.size() == leaves.size() && seconds > 0;
  // Per touched voxel: its slot in `sums`, filled in leaf order.
  std::unordered_map<int64_t, uint32_t> slot;
  std::vector<std::pair<Vec3, uint32_t>> sums;
  for (size_t k = 0; k < leaves.size(); ++k) {
    if ((k & (kPollLeaves - 1)) == 0 && OrNull(interrupter).WasInterrupted(k, leaves.size()))
      return absl::CancelledError("interrupted");
    const Vec3 p = leaves[k];
    int v[3];
    bool inside = true;
    for (int a = 0; a < 3; ++a) {
      const double f = std::floor((p[a] - frame.bounds.min[a]) / h[a]);
      inside = inside && f >= 0 && f < r[a];
      v[a] = inside ? int(f) : 0;
    }
    if (!inside) {
      ++g.outside;
      continue;
    }
    g.counts.Add(v[0], v[1], v[2]);
    if (!velocity) continue;
    const int64_t voxel = (int64_t(v[0]) * r.y + v[1]) * r.z + v[2];
    auto [it, fresh] = slot.try_emplace(voxel, uint32_t(sums.size()));
    if (fresh) sums.push_back({Vec3{}, 0});
    auto& [sum, n] = sums[it->second];
    if (have_prev) sum = sum + (1.0 / seconds) * (p - prev[k]);
    ++n;
  }
  if (!velocity) return g;
  // Voxels in index order, so the written grid does not depend on hashing.
  std::vector<std::pair<int64_t, uint32_t>> order(slot.begin(), slot.end());
  std::sort(order.begin(), order.end());
  g.velocity.voxels.reserve(order.size());
  for (const auto& [voxel, s] : order) {
    const Int3 c{int32_t(voxel / (int64_t(r.y) * r.z)), int32_t((voxel / r.z) % r.y),
                 int32_t(voxel % r.z)};
    g.velocity.voxels.emplace_back(c, (1.0 / double(sums[s].second)) * sums[s].first);
  }
  return g;
}

}  // namespace nimbus
