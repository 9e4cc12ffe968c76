#include "core/chaos_game.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <thread>

#include "absl/strings/str_cat.h"

namespace nimbus {

namespace {
// Bytes per key in a worker's buffer and its binning scratch.
constexpr uint64_t kKeyBytes = 2 * sizeof(uint64_t);
}  // namespace

struct ChaosGame::Worker {
  CountGrid* grid = nullptr;
  std::vector<uint64_t> keys;
  std::vector<uint64_t> scratch;
  size_t n = 0;
  ChaosGameStats stats;

  bool weighted = true;  // false: plain keys, the cheapest increments

  void Flush() {
    grid->AddKeys(keys.data(), n, scratch, weighted);
    n = 0;
  }
};

ChaosGame::ChaosGame(ChaosGameParams params, int threads)
    : params_(std::move(params)), threads_(std::max(1, threads)) {}

ChaosGame::~ChaosGame() = default;

absl::StatusOr<std::unique_ptr<ChaosGame>> ChaosGame::Create(ChaosGameParams params,
                                                             int threads) {
  if (params.ifs.maps.empty()) return absl::InvalidArgumentError("the IFS has no maps");
  const Int3 r = params.frame.resolution;
  if (r.x <= 0 || r.y <= 0 || r.z <= 0)
    return absl::InvalidArgumentError("grid resolution must be positive on every axis");
  const Vec3 size = params.frame.bounds.Size();
  if (!(size.x > 0 && size.y > 0 && size.z > 0))
    return absl::InvalidArgumentError("grid bounds must have max > min on every axis");
  std::unique_ptr<ChaosGame> game(new ChaosGame(std::move(params), threads));
  const ChaosGameParams& p = game->params_;
  const Ifs& ifs = p.ifs;  // the moved-into copy
  if (p.chain) {
    if (p.chain->states.empty()) return absl::InvalidArgumentError("the chain has no states");
    if (p.chain->start_state >= p.chain->states.size())
      return absl::InvalidArgumentError("the chain's start state does not exist");
    for (size_t s = 0; s < p.chain->states.size(); ++s) {
      const ChainState& st = p.chain->states[s];
      if (st.transitions.empty() || st.transitions.size() != st.probabilities.size())
        return absl::InvalidArgumentError(
            absl::StrCat("chain state ", s, " needs transitions with one probability each"));
      for (const ChainTransition& t : st.transitions)
        if (t.map >= ifs.maps.size() || t.next_state >= p.chain->states.size())
          return absl::InvalidArgumentError(
              absl::StrCat("chain state ", s, " has a transition to a missing map or state"));
      game->state_tables_.emplace_back(st.probabilities);
    }
  } else {
    if (ifs.probabilities.size() != ifs.maps.size())
      return absl::InvalidArgumentError("need one probability per map");
    double total = 0;
    for (double q : ifs.probabilities) {
      if (!(q >= 0)) return absl::InvalidArgumentError("probabilities must be >= 0");
      total += q;
    }
    if (!(total > 0)) return absl::InvalidArgumentError("probabilities must not all be 0");
    game->map_table_ = AliasTable(ifs.probabilities);
  }
  if (p.color.mode != ColorMode::kNone && !(p.color.blend > 0 && p.color.blend <= 1))
    return absl::InvalidArgumentError("colour blend must be in (0, 1]");
  game->num_chunks_ = (p.iterations + kChunkIterations - 1) / kChunkIterations;
  const bool color = p.color.mode != ColorMode::kNone;
  for (int t = 0; t < game->threads_; ++t) {
    game->counts_.emplace_back(r, color);
    auto w = std::make_unique<Worker>();
    w->keys.resize(KeyBatch(p));
    w->scratch.resize(w->keys.size());  // sized once: memory stays as estimated
    w->weighted = p.splat;
    game->workers_.push_back(std::move(w));
  }
  for (int t = 0; t < game->threads_; ++t) game->workers_[t]->grid = &game->counts_[t];
  return game;
}

namespace {

// Tiles of the grid that plotted points can reach. For contractive affine
// maps plotted as they are, the attractor lies in a ball B(c, R) that every
// map sends into itself: |A_i c + b_i - c| + s_i R <= R, s_i the map's
// largest singular value. Walkers enter it to within s_max^warmup times
// their starting distance before they plot. Otherwise: the whole grid.
uint64_t ReachableTiles(const ChaosGameParams& p) {
  const Int3 r = p.frame.resolution;
  const uint64_t all = uint64_t((r.x + 31) / 32) * ((r.y + 31) / 32) * ((r.z + 31) / 32);
  if (p.ifs.final_map || p.ifs.arcs || !p.ifs.AllAffine() || p.ifs.maps.empty()) return all;
  Vec3 c;
  double s_max = 0;
  for (const PointMap& m : p.ifs.maps) {
    const double s = m.pre.ContractionFactor();
    if (!(s < 1)) return all;
    s_max = std::max(s_max, s);
    Vec3 fixed;  // the map's fixed point, by iteration
    for (int i = 0; i < 2000; ++i) fixed = m.pre.Apply(fixed);
    c = c + fixed;
  }
  c = (1.0 / double(p.ifs.maps.size())) * c;
  double radius = 0;
  for (const PointMap& m : p.ifs.maps)
    radius = std::max(radius, Length(m.pre.Apply(c) - c) / (1 - m.pre.ContractionFactor()));
  const Bounds& b = p.frame.bounds;
  const double start = Length(b.max - b.min) + Length(c - b.min) + radius;
  const Vec3 vs = p.frame.VoxelSize();
  radius += std::pow(s_max, double(p.warmup)) * start + Length(vs);
  if (!std::isfinite(radius)) return all;
  uint64_t tiles = 1;
  for (int a = 0; a < 3; ++a) {
    const int n = a == 0 ? r.x : (a == 1 ? r.y : r.z);
    const double lo = std::floor((c[a] - radius - b.min[a]) / vs[a]);
    const double hi = std::floor((c[a] + radius - b.min[a]) / vs[a]);
    const int t0 = int(std::clamp(lo, 0.0, double(n - 1))) / 32;
    const int t1 = int(std::clamp(hi, 0.0, double(n - 1))) / 32;
    tiles *= uint64_t(t1 - t0 + 1);
  }
  return std::min(tiles, all);
}

}  // namespace

size_t ChaosGame::KeyBatch(const ChaosGameParams& p) {
  // A flush pulls each active tile (2048 cache lines) into L2 once; with
  // ~8192 keys per tile every line fetched serves ~4 increments instead of
  // one miss per increment. Bounded so the buffers (16 bytes per key with
  // the binning scratch) stay at 512 MiB per thread, which 1024^3 grids and
  // larger reach (their counters can take gigabytes).
  const uint64_t tiles = ReachableTiles(p);
  // A thread never buffers more keys than the whole job plots.
  const uint64_t batch = std::min(tiles * 8192, std::max<uint64_t>(p.iterations, 1));
  return size_t(std::clamp<uint64_t>(batch, uint64_t{1} << 16, uint64_t{1} << 25));
}

ChaosGameMemory ChaosGame::EstimateMemory(const ChaosGameParams& p, int threads,
                                          uint64_t output_bytes_per_voxel) {
  threads = std::max(1, threads);
  const Int3 r = p.frame.resolution;
  const bool color = p.color.mode != ColorMode::kNone;
  const uint64_t tiles = ReachableTiles(p);
  // Every plotted step lands in at most one tile of one thread, so the
  // tiles of all threads together are bounded by the iterations as well as
  // by threads x the reachable tiles.
  const uint64_t touches = (p.iterations + uint64_t(threads) * kWalkers) * (p.splat ? 8 : 1);
  const uint64_t all_tiles = std::min(tiles * uint64_t(threads), touches);
  ChaosGameMemory m;
  m.accumulation = uint64_t(threads) * CountGrid::BoundedMemoryBytes(r, 0, color) +
                   all_tiles * CountGrid::TileBytes(color) +
                   uint64_t(threads) * KeyBatch(p) * kKeyBytes;
  // Output: the merged grid, plus one VDB leaf (8^3 voxels, with ~15 %
  // tree overhead) per touched leaf.
  const uint64_t merged = CountGrid::BoundedMemoryBytes(r, std::min(tiles, touches), color);
  const uint64_t leaves = std::min(tiles * 64, touches);
  m.output = merged + leaves * 512 * output_bytes_per_voxel * 115 / 100;
  return m;
}

uint64_t ChaosGame::MemoryBytes() const {
  uint64_t bytes = 0;
  for (const CountGrid& g : counts_) bytes += g.MemoryBytes();
  for (const auto& w : workers_) bytes += (w->keys.capacity() + w->scratch.capacity()) * 8;
  return bytes;
}

ChaosGameStats ChaosGame::stats() const {
  ChaosGameStats s;
  for (const auto& w : workers_) {
    s.iterations_done += w->stats.iterations_done;
    s.outside += w->stats.outside;
    s.reseeded += w->stats.reseeded;
    s.final_nonfinite += w->stats.final_nonfinite;
  }
  return s;
}

template <bool kColor>
void ChaosGame::RunChunkAffine(uint64_t chunk, Worker& w) {
  const ChaosGameParams& p = params_;
  const uint64_t begin = chunk * kChunkIterations;
  const uint64_t count = std::min(kChunkIterations, p.iterations - begin);
  Rng rng(p.seed, chunk);

  const Bounds b = p.frame.bounds;
  const Int3 res = p.frame.resolution;
  const Vec3 vs = p.frame.VoxelSize();
  const double ix = 1.0 / vs.x, iy = 1.0 / vs.y, iz = 1.0 / vs.z;
  const double rx = res.x, ry = res.y, rz = res.z;
  const uint64_t ty = uint64_t(w.grid->tiles().y), tz = uint64_t(w.grid->tiles().z);
  const std::vector<PointMap>& maps = p.ifs.maps;
  // Local copies: stores into the key buffer cannot alias them.
  std::vector<Affine3> affine(maps.size());
  std::vector<double> color_of(maps.size());
  for (size_t i = 0; i < maps.size(); ++i) {
    affine[i] = maps[i].pre;
    color_of[i] = maps[i].color;
  }
  const Affine3* A = affine.data();
  const AliasTable table = map_table_;
  const bool by_address = p.color.mode == ColorMode::kAddress;
  const double blend = p.color.blend;
  const double inv_maps = 1.0 / double(maps.size());
  uint64_t reseeded = 0, outside = 0;

  Vec3 pos[kWalkers];
  double addr[kWalkers], col[kWalkers];
  auto random_point = [&] {
    return Vec3{rng.Uniform(b.min.x, b.max.x), rng.Uniform(b.min.y, b.max.y),
                rng.Uniform(b.min.z, b.max.z)};
  };
  auto step = [&](int k) {
    const uint32_t map = table.Sample(rng.Next());
    pos[k] = A[map].Apply(pos[k]);
    if constexpr (kColor) {
      addr[k] = (double(map) + addr[k]) * inv_maps;
      const double target = by_address ? addr[k] : color_of[map];
      col[k] += blend * (target - col[k]);
    }
    return IsFinite(pos[k]);
  };
  auto warm_up = [&](int k) {
    pos[k] = random_point();
    if constexpr (kColor) addr[k] = col[k] = rng.Uniform();
    for (uint32_t i = 0; i < p.warmup; ++i) {
      if (!step(k)) {
        pos[k] = random_point();
        ++reseeded;
      }
    }
  };
  for (int k = 0; k < kWalkers; ++k) warm_up(k);

  uint64_t* keys = w.keys.data();
  const size_t cap = w.keys.size();
  size_t n = w.n;
  auto advance = [&](int k) {
    if (!step(k)) [[unlikely]] {
      ++reseeded;
      warm_up(k);
      return;
    }
    const double fx = (pos[k].x - b.min.x) * ix, fy = (pos[k].y - b.min.y) * iy,
                 fz = (pos[k].z - b.min.z) * iz;
    if (!(fx >= 0 && fx < rx && fy >= 0 && fy < ry && fz >= 0 && fz < rz)) [[unlikely]] {
      ++outside;
      return;
    }
    const int x = int(fx), y = int(fy), z = int(fz);
    const uint64_t tile = (uint64_t(x >> 5) * ty + uint64_t(y >> 5)) * tz + uint64_t(z >> 5);
    uint64_t key = (tile << 15) | CountGrid::LocalOffset(x & 31, y & 31, z & 31);
    if constexpr (kColor) {
      const double c = std::clamp(col[k], 0.0, 1.0);
      key = CountGrid::WithColor(key, uint32_t(c * CountGrid::kColorScale + 0.5));
    }
    keys[n++] = key;
  };
  const uint64_t rounds = count / kWalkers;
  const int tail = int(count % kWalkers);
  for (uint64_t r = 0; r < rounds; ++r) {
    if (n + kWalkers > cap) {
      w.n = n;
      w.Flush();
      n = 0;
    }
    for (int k = 0; k < kWalkers; ++k) advance(k);
  }
  if (n + kWalkers > cap) {
    w.n = n;
    w.Flush();
    n = 0;
  }
  for (int k = 0; k < tail; ++k) advance(k);
  w.n = n;
  w.stats.reseeded += reseeded;
  w.stats.outside += outside;
  w.stats.iterations_done += count;
}

void ChaosGame::RunChunk(uint64_t chunk, Worker& w) {
  const ChaosGameParams& p = params_;
  if (!p.chain && !p.ifs.final_map && !p.ifs.arcs && !p.splat && p.ifs.AllAffine()) {
    if (p.color.mode == ColorMode::kNone)
      RunChunkAffine<false>(chunk, w);
    else
      RunChunkAffine<true>(chunk, w);
    return;
  }
  const uint64_t begin = chunk * kChunkIterations;
  const uint64_t count = std::min(kChunkIterations, p.iterations - begin);
  Rng rng(p.seed, chunk);

  const Bounds& b = p.frame.bounds;
  const Int3 res = p.frame.resolution;
  const Vec3 vs = p.frame.VoxelSize();
  const double ix = 1.0 / vs.x, iy = 1.0 / vs.y, iz = 1.0 / vs.z;
  const std::vector<PointMap>& maps = p.ifs.maps;
  const PointMap* final_map = p.ifs.final_map ? &*p.ifs.final_map : nullptr;
  const ArcsTransform* arcs = p.ifs.arcs ? &*p.ifs.arcs : nullptr;
  const bool has_final = final_map || arcs;
  const MarkovChain* chain = p.chain ? &*p.chain : nullptr;
  const bool affine = p.ifs.AllAffine();
  const ColorMode color_mode = p.color.mode;
  const double blend = p.color.blend;
  const double inv_maps = 1.0 / double(maps.size());
  const bool splat = p.splat;
  const size_t keys_per_round = splat ? 8 * kWalkers : kWalkers;

  Vec3 pos[kWalkers];
  uint32_t state[kWalkers];
  double addr[kWalkers], col[kWalkers];
  auto random_point = [&] {
    return Vec3{rng.Uniform(b.min.x, b.max.x), rng.Uniform(b.min.y, b.max.y),
                rng.Uniform(b.min.z, b.max.z)};
  };
  // One step of walker k; returns false if its point went non-finite.
  auto step = [&](int k) {
    uint32_t map;
    if (chain) {
      const ChainState& st = chain->states[state[k]];
      const ChainTransition& t = st.transitions[state_tables_[state[k]].Sample(rng.Next())];
      map = t.map;
      state[k] = t.next_state;
    } else {
      map = map_table_.Sample(rng.Next());
    }
    pos[k] = affine ? maps[map].pre.Apply(pos[k]) : maps[map].Apply(pos[k], rng);
    if (color_mode != ColorMode::kNone) {
      addr[k] = (double(map) + addr[k]) * inv_maps;
      const double target = color_mode == ColorMode::kAddress ? addr[k] : maps[map].color;
      col[k] += blend * (target - col[k]);
    }
    return IsFinite(pos[k]);
  };
  auto warm_up = [&](int k) {
    pos[k] = random_point();
    state[k] = chain ? chain->start_state : 0;
    if (color_mode != ColorMode::kNone) addr[k] = col[k] = rng.Uniform();
    for (uint32_t i = 0; i < p.warmup; ++i) {
      if (!step(k)) {
        pos[k] = random_point();
        ++w.stats.reseeded;
      }
    }
  };
  // `n` is the global index of the plotted step (the arcs' phase).
  auto plot = [&](int k, uint64_t n) {
    if (chain && !chain->states[state[k]].plotted) return;
    Vec3 q = pos[k];
    if (has_final) {
      if (final_map) q = final_map->Apply(q, rng);
      if (arcs) q = arcs->Apply(q, n);
      if (!IsFinite(q)) {
        ++w.stats.final_nonfinite;
        ++w.stats.outside;
        return;
      }
    }
    const double fx = (q.x - b.min.x) * ix, fy = (q.y - b.min.y) * iy, fz = (q.z - b.min.z) * iz;
    // Written so NaN fails the test and counts as outside.
    if (!(fx >= 0 && fx < res.x && fy >= 0 && fy < res.y && fz >= 0 && fz < res.z)) {
      ++w.stats.outside;
      return;
    }
    uint64_t color_bits = 0;
    if (color_mode != ColorMode::kNone) {
      const double c = std::clamp(col[k], 0.0, 1.0);
      color_bits = CountGrid::WithColor(0, uint32_t(c * CountGrid::kColorScale + 0.5));
    }
    if (!splat) {
      w.keys[w.n++] = w.grid->Key(int(fx), int(fy), int(fz)) | color_bits;
      return;
    }
    // Voxel centres sit at i + 0.5: the point lies between centres i0 and
    // i0 + 1 on each axis, at quarter q (0..4) of the way. Corners outside
    // the grid fold onto the border voxel so every point adds exactly 64.
    int i0[3], quarter[3];
    const double f[3] = {fx - 0.5, fy - 0.5, fz - 0.5};
    for (int a = 0; a < 3; ++a) {
      const double fl = std::floor(f[a]);
      i0[a] = int(fl);
      quarter[a] = int(std::lround((f[a] - fl) * 4));
    }
    const int lim[3] = {res.x - 1, res.y - 1, res.z - 1};
    for (int c = 0; c < 8; ++c) {
      uint32_t weight = 1;
      int v[3];
      for (int a = 0; a < 3; ++a) {
        const int hi = (c >> a) & 1;
        weight *= uint32_t(hi ? quarter[a] : 4 - quarter[a]);
        v[a] = std::clamp(i0[a] + hi, 0, lim[a]);
      }
      if (weight == 0) continue;
      w.keys[w.n++] =
          CountGrid::WithWeight(w.grid->Key(v[0], v[1], v[2]), weight) | color_bits;
    }
  };
  auto advance = [&](int k, uint64_t n) {
    if (!step(k)) {
      ++w.stats.reseeded;
      warm_up(k);
      return;
    }
    plot(k, n);
  };

  for (int k = 0; k < kWalkers; ++k) warm_up(k);
  const uint64_t rounds = count / kWalkers;
  const int tail = int(count % kWalkers);
  uint64_t n = begin;
  for (uint64_t r = 0; r < rounds; ++r) {
    if (w.n + keys_per_round > w.keys.size()) w.Flush();
    for (int k = 0; k < kWalkers; ++k) advance(k, n++);
  }
  if (w.n + keys_per_round > w.keys.size()) w.Flush();
  for (int k = 0; k < tail; ++k) advance(k, n++);
  w.stats.iterations_done += count;
}

absl::Status ChaosGame::RunUntil(uint64_t iterations, Interrupter* interrupter) {
  Interrupter& intr = OrNull(interrupter);
  const uint64_t target =
      std::min(num_chunks_, (iterations + kChunkIterations - 1) / kChunkIterations);
  if (next_chunk_ >= target) return absl::OkStatus();
  std::atomic<uint64_t> next{next_chunk_};
  std::atomic<bool> stop{false};
  auto body = [&](int t) {
    Worker& w = *workers_[t];
    while (!stop.load(std::memory_order_relaxed)) {
      const uint64_t c = next.fetch_add(1);
      if (c >= target) break;
      RunChunk(c, w);
      if (intr.WasInterrupted(c * kChunkIterations, params_.iterations)) stop = true;
    }
    w.Flush();
  };
  const int n = int(std::min<uint64_t>(threads_, target - next_chunk_));
  std::vector<std::thread> pool;
  for (int t = 1; t < n; ++t) pool.emplace_back(body, t);
  body(0);
  for (auto& th : pool) th.join();
  if (stop) return absl::CancelledError("interrupted");
  next_chunk_ = target;
  return absl::OkStatus();
}

std::vector<uint64_t> CoarseCounts(const std::vector<const CountGrid*>& parts,
                                   int max_resolution) {
  if (parts.empty()) return {};
  const Int3 r = parts[0]->resolution();
  // Whole tiles per cell keeps this a pass over tile sums.
  int cell = CountGrid::kTileDim;
  while ((std::max({r.x, r.y, r.z}) + cell - 1) / cell > max_resolution) cell *= 2;
  const Int3 c{(r.x + cell - 1) / cell, (r.y + cell - 1) / cell, (r.z + cell - 1) / cell};
  std::vector<uint64_t> out(size_t(c.x) * c.y * c.z, 0);
  for (const CountGrid* g : parts) {
    g->ForEachTile([&](Int3 o, const uint32_t* t) {
      uint64_t sum = 0;
      for (int i = 0; i < CountGrid::kTileVoxels; ++i) sum += t[i];
      out[(size_t(o.x / cell) * c.y + o.y / cell) * c.z + o.z / cell] += sum;
    });
  }
  return out;
}

double DensityChange(const std::vector<uint64_t>& a, const std::vector<uint64_t>& b) {
  if (a.size() != b.size()) return 2;
  uint64_t ta = 0, tb = 0;
  for (uint64_t v : a) ta += v;
  for (uint64_t v : b) tb += v;
  if (ta == 0 || tb == 0) return ta == tb ? 0 : 2;
  double d = 0;
  for (size_t i = 0; i < a.size(); ++i) d += std::fabs(double(a[i]) / ta - double(b[i]) / tb);
  return d;
}

CountGrid ChaosGame::TakeCounts() {
  workers_.clear();  // the key buffers first: lowers the merge's peak
  CountGrid out = std::move(counts_[0]);
  for (size_t t = 1; t < counts_.size(); ++t) {
    out.Merge(counts_[t]);
    counts_[t] = CountGrid(params_.frame.resolution);  // release memory early
  }
  counts_.clear();
  workers_.clear();
  return out;
}

}  // namespace nimbus
