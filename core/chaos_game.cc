#include "core/chaos_game.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <thread>

#include "absl/strings/str_cat.h"

namespace nimbus {

namespace {
// Keys buffered per worker before a binned flush into its CountGrid.
constexpr size_t kKeyBatch = size_t{1} << 16;
}  // namespace

struct ChaosGame::Worker {
  CountGrid* grid = nullptr;
  std::vector<uint64_t> keys;
  std::vector<uint64_t> scratch;
  size_t n = 0;
  ChaosGameStats stats;

  void Flush() {
    grid->AddKeys(keys.data(), n, scratch);
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
  game->num_chunks_ = (p.iterations + kChunkIterations - 1) / kChunkIterations;
  for (int t = 0; t < game->threads_; ++t) {
    game->counts_.emplace_back(r);
    auto w = std::make_unique<Worker>();
    w->keys.resize(kKeyBatch);
    game->workers_.push_back(std::move(w));
  }
  for (int t = 0; t < game->threads_; ++t) game->workers_[t]->grid = &game->counts_[t];
  return game;
}

uint64_t ChaosGame::EstimateMemoryBytes(Int3 resolution, int threads) {
  return CountGrid::MaxMemoryBytes(resolution) * uint64_t(std::max(1, threads)) +
         uint64_t(std::max(1, threads)) * kKeyBatch * 2 * sizeof(uint64_t);
}

ChaosGameStats ChaosGame::stats() const {
  ChaosGameStats s;
  for (const auto& w : workers_) {
    s.iterations_done += w->stats.iterations_done;
    s.outside += w->stats.outside;
    s.reseeded += w->stats.reseeded;
  }
  return s;
}

void ChaosGame::RunChunk(uint64_t chunk, Worker& w) {
  const ChaosGameParams& p = params_;
  const uint64_t begin = chunk * kChunkIterations;
  const uint64_t count = std::min(kChunkIterations, p.iterations - begin);
  Rng rng(p.seed, chunk);

  const Bounds& b = p.frame.bounds;
  const Int3 res = p.frame.resolution;
  const Vec3 vs = p.frame.VoxelSize();
  const double ix = 1.0 / vs.x, iy = 1.0 / vs.y, iz = 1.0 / vs.z;
  const std::vector<PointMap>& maps = p.ifs.maps;
  const PointMap* final_map = p.ifs.final_map ? &*p.ifs.final_map : nullptr;
  const MarkovChain* chain = p.chain ? &*p.chain : nullptr;
  const bool affine = p.ifs.AllAffine();

  Vec3 pos[kWalkers];
  uint32_t state[kWalkers];
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
    return IsFinite(pos[k]);
  };
  auto warm_up = [&](int k) {
    pos[k] = random_point();
    state[k] = chain ? chain->start_state : 0;
    for (uint32_t i = 0; i < p.warmup; ++i) {
      if (!step(k)) {
        pos[k] = random_point();
        ++w.stats.reseeded;
      }
    }
  };
  auto plot = [&](int k) {
    if (chain && !chain->states[state[k]].plotted) return;
    Vec3 q = final_map ? final_map->Apply(pos[k], rng) : pos[k];
    const double fx = (q.x - b.min.x) * ix, fy = (q.y - b.min.y) * iy, fz = (q.z - b.min.z) * iz;
    // Written so NaN fails the test and counts as outside.
    if (!(fx >= 0 && fx < res.x && fy >= 0 && fy < res.y && fz >= 0 && fz < res.z)) {
      ++w.stats.outside;
      return;
    }
    w.keys[w.n++] = w.grid->Key(int(fx), int(fy), int(fz));
  };
  auto advance = [&](int k) {
    if (!step(k)) {
      ++w.stats.reseeded;
      warm_up(k);
      return;
    }
    plot(k);
  };

  for (int k = 0; k < kWalkers; ++k) warm_up(k);
  const uint64_t rounds = count / kWalkers;
  const int tail = int(count % kWalkers);
  for (uint64_t r = 0; r < rounds; ++r) {
    if (w.n + kWalkers > w.keys.size()) w.Flush();
    for (int k = 0; k < kWalkers; ++k) advance(k);
  }
  if (w.n + kWalkers > w.keys.size()) w.Flush();
  for (int k = 0; k < tail; ++k) advance(k);
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

CountGrid ChaosGame::TakeCounts() {
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
