#include "core/field/field_grid.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <atomic>
#include <optional>
#include <cmath>
#include <vector>

#include "absl/strings/str_cat.h"
#include "core/field/node_hash.h"

namespace nimbus {

namespace {

constexpr int kMaxTaps = 4;

/// @brief The stencil of one axis of one mesh for every sample along it:
/// its first node slot and tap weights; and per slot, the wrapped node
/// index (the coordinate NodeValue hashes).
struct AxisTable {
  int taps = 1;
  int slots = 1;
  std::vector<int32_t> first{0};
  // Per sample x taps: C opens the recursion (the whole 1D interpolant),
  // A and B are the Hermite value and derivative parts, L is linear.
  std::vector<float> wc{1}, wa{1}, wb{0}, wl{1};
  std::vector<uint64_t> hash{0};
  // For the innermost (z) axis: the weights again, tap-major (tap d of
  // sample j at d * samples + j), and the runs of samples that share a
  // stencil, so the z fold vectorises over each run.
  struct Run {
    int begin, end, first;
  };
  std::vector<float> za{1}, zb{0}, zl{1};
  std::vector<Run> runs{{0, 1, 0}};
};

// Fills the tap-major weights and runs of `t` (`a_of` picks the value
// weights: A for pseudo-cubic, C otherwise).
void AddRuns(AxisTable& t, bool pseudo_cubic) {
  const size_t n = t.first.size(), taps = size_t(t.taps);
  t.za.resize(n * taps);
  t.zb.resize(n * taps);
  t.zl.resize(n * taps);
  for (size_t j = 0; j < n; ++j)
    for (size_t d = 0; d < taps; ++d) {
      t.za[d * n + j] = pseudo_cubic ? t.wa[j * taps + d] : t.wc[j * taps + d];
      t.zb[d * n + j] = t.wb[j * taps + d];
      t.zl[d * n + j] = t.wl[j * taps + d];
    }
  t.runs.clear();
  for (size_t j = 0; j < n; ++j) {
    if (!t.runs.empty() && t.runs.back().first == t.first[j] && t.runs.back().end == int(j))
      ++t.runs.back().end;
    else
      t.runs.push_back({int(j), int(j) + 1, t.first[j]});
  }
}

void StencilWeights(FieldInterpolation interp, double t, float* c, float* a, float* b, float* l) {
  if (interp == FieldInterpolation::kCubic) {
    // One channel: Catmull-Rom on every axis.
    const auto cr = CatmullRom(t);
    for (int d = 0; d < 4; ++d) {
      c[d] = a[d] = l[d] = float(cr[size_t(d)]);
      b[d] = 0;
    }
    return;
  }
  if (interp != FieldInterpolation::kPseudoCubic) {
    const double s = interp == FieldInterpolation::kQuintic ? QuinticFade(t) : t;
    c[0] = a[0] = l[0] = float(1 - s);
    c[1] = a[1] = l[1] = float(s);
    b[0] = b[1] = 0;
    return;
  }
  // Nodes -1, 0, 1, 2 of the cell; derivatives are central differences.
  const auto h = HermiteBasis(t);
  const double av[4] = {0, h[0], h[1], 0};
  const double bv[4] = {-h[2] / 2, -h[3] / 2, h[2] / 2, h[3] / 2};
  const double lv[4] = {0, 1 - t, t, 0};
  for (int d = 0; d < 4; ++d) {
    a[d] = float(av[d]);
    b[d] = float(bv[d]);
    c[d] = float(av[d] + bv[d]);
    l[d] = float(lv[d]);
  }
}

// The table of field axis `axis` for mesh k, from the field coordinate of
// each sample. False when the samples touch far more nodes than they are
// (cells much finer than the grid): the point evaluator is then cheaper.
bool BuildAxis(const FractalField& f, size_t k, int axis, const std::vector<double>& u,
               AxisTable& out) {
  const FieldMesh& mesh = f.params().meshes[k];
  const bool four = FourTap(f.params().interpolation);
  const int taps = four ? 4 : 2, shift = four ? -1 : 0;
  const size_t n = u.size();
  std::vector<int64_t> start(n);
  std::vector<double> frac(n);
  for (size_t j = 0; j < n; ++j) {
    const double m = u[j] / mesh.cell[axis] + mesh.offset[axis];
    const double fl = std::floor(m);
    start[j] = int64_t(fl) + shift;
    frac[j] = m - fl;
  }
  const auto [lo, hi] = std::minmax_element(start.begin(), start.end());
  const int64_t span = *hi - *lo + taps;
  if (span > int64_t(2 * n * taps + 8)) return false;
  out.taps = taps;
  out.slots = int(span);
  out.first.resize(n);
  out.wc.resize(n * taps);
  out.wa.resize(n * taps);
  out.wb.resize(n * taps);
  out.wl.resize(n * taps);
  for (size_t j = 0; j < n; ++j) {
    out.first[j] = int32_t(start[j] - *lo);
    StencilWeights(f.params().interpolation, frac[j], &out.wc[j * taps], &out.wa[j * taps],
                   &out.wb[j * taps], &out.wl[j * taps]);
  }
  out.hash.resize(size_t(span));
  const int64_t per = mesh.period_nodes[axis];
  for (int64_t s = 0; s < span; ++s) {
    int64_t node = *lo + s;
    if (per > 0) node = ((node % per) + per) % per;
    out.hash[size_t(s)] = uint64_t(node);
  }
  return true;
}

struct MeshTables {
  bool separable = false;
  AxisTable axis[3];  // spatial x, y, z (degenerate beyond space_dims)
  AxisTable time;     // degenerate without a time axis
  bool time_derivative = false;  // pseudo-cubic with a time axis: a B plane
};

// Field coordinates of the samples along spatial axis i (the mapping is
// diagonal, so each depends on its own axis only).
std::vector<double> AxisCoords(const FractalField& f, const FieldGrid& g, int i) {
  std::vector<double> u(size_t(g.count[i]));
  for (int j = 0; j < g.count[i]; ++j) {
    double x[3] = {0, 0, 0};
    x[i] = g.origin[i] + j * g.step[i];
    u[size_t(j)] = f.Map(x, g.time)[i];
  }
  return u;
}

MeshTables BuildTables(const FractalField& f, size_t k, const FieldGrid& g) {
  MeshTables t;
  const FractalFieldParams& p = f.params();
  const int s = p.mapping.space_dims;
  if (p.meshes[k].rotated || !p.mapping.Diagonal()) return t;
  for (int i = 0; i < s; ++i)
    if (!BuildAxis(f, k, i, AxisCoords(f, g, i), t.axis[i])) return t;
  if (s == 3) AddRuns(t.axis[2], p.interpolation == FieldInterpolation::kPseudoCubic);
  if (p.dims > s) {
    double x[3] = {0, 0, 0};
    if (!BuildAxis(f, k, s, {f.Map(x, g.time)[s]}, t.time)) return t;
    t.time_derivative = p.interpolation == FieldInterpolation::kPseudoCubic;
  }
  t.separable = true;
  return t;
}

/// @brief Scratch of one slab task for one mesh: a ring of node planes
/// (time folded in) and the x- and y-folded channels.
class SlabKernel {
 public:
  SlabKernel(const FractalField& f, size_t k, const MeshTables& t, const FieldGrid& g)
      : t_(t), g_(g), key_(MeshPrefix(f.params().seed, uint32_t(k))),
        weight_(float(f.params().meshes[k].weight)),
        cubic_(f.params().interpolation == FieldInterpolation::kPseudoCubic),
        sy_(t.axis[1].slots), sz_(t.axis[2].slots), plane_(size_t(sy_) * size_t(sz_)) {
    kinds_ = t.time_derivative ? 2 : 1;
    ring_ = t.axis[0].taps;
    planes_.assign(size_t(ring_ * kinds_) * plane_, 0.f);
    tags_.assign(size_t(ring_), -1);
    gc_.resize(plane_);
    if (cubic_) gl_.resize(plane_);
    if (kinds_ == 2) gb_.resize(plane_);
    const size_t ny = size_t(g.count[1]);
    hc_.resize(ny * size_t(sz_));
    if (cubic_) hl_.resize(ny * size_t(sz_));
    if (kinds_ == 2) hb_.resize(ny * size_t(sz_));
  }

  // Adds weight * f_k at every sample of x row `x` into `out`.
  void Row(int x, float* out) {
    const AxisTable& X = t_.axis[0];
    const int fx = X.first[size_t(x)];
    for (int d = 0; d < X.taps; ++d) EnsurePlane(fx + d);
    FoldX(x, fx);
    FoldY();
    FoldZ(out + size_t(x) * size_t(g_.count[1]) * size_t(g_.count[2]));
  }

 private:
  float* Plane(int slot, int kind) {
    return &planes_[(size_t(slot % ring_) * size_t(kinds_) + size_t(kind)) * plane_];
  }

  // Hashes the nodes of x slot `slot` (every y, z slot and time tap) and
  // folds the time axis: kind 0 with its A (or C) weights, kind 1 with B.
  void EnsurePlane(int slot) {
    if (tags_[size_t(slot % ring_)] == slot) return;
    tags_[size_t(slot % ring_)] = slot;
    const AxisTable &X = t_.axis[0], &Y = t_.axis[1], &Z = t_.axis[2], &T = t_.time;
    float* pa = Plane(slot, 0);
    float* pb = kinds_ == 2 ? Plane(slot, 1) : nullptr;
    // Linear and quintic use C = A; the pseudo-cubic time axis opens with A
    // for the value channel (its derivative part goes to kind 1).
    const float* wa = cubic_ ? T.wa.data() : T.wc.data();
    // HashCoords(seed, k, x, y, z, t), one link of its chain per loop level.
    const uint64_t hx = Mix64(key_ ^ X.hash[size_t(slot)]);
    for (int y = 0; y < sy_; ++y) {
      const uint64_t hxy = Mix64(hx ^ Y.hash[size_t(y)]);
      float* __restrict ra = pa + size_t(y) * size_t(sz_);
      float* rb = pb ? pb + size_t(y) * size_t(sz_) : nullptr;
      const uint64_t* __restrict zh = Z.hash.data();
      if (T.taps == 1 && !rb) {  // one node per entry
        const uint64_t ht = T.hash[size_t(T.first[0])];
        for (int z = 0; z < sz_; ++z) ra[z] = wa[0] * HashToValue(Mix64(Mix64(hxy ^ zh[z]) ^ ht));
        continue;
      }
      for (int z = 0; z < sz_; ++z) {
        const uint64_t hxyz = Mix64(hxy ^ zh[z]);
        float va = 0, vb = 0;
        for (int d = 0; d < T.taps; ++d) {
          const float v = HashToValue(Mix64(hxyz ^ T.hash[size_t(T.first[0] + d)]));
          va += wa[d] * v;
          if (rb) vb += T.wb[size_t(d)] * v;
        }
        ra[z] = va;
        if (rb) rb[z] = vb;
      }
    }
  }

  static void Axpy(float w, const float* __restrict src, float* __restrict dst, size_t n) {
    if (w == 0) return;
    for (size_t i = 0; i < n; ++i) dst[i] += w * src[i];
  }

  // dst = Σ_d w[d] src[d] in one pass (dst is overwritten).
  static void Combine(const float* w, const float* const* src, int taps, float* __restrict dst,
                      size_t n) {
    if (taps == 1) {
      const float w0 = w[0];
      const float* __restrict s0 = src[0];
      for (size_t i = 0; i < n; ++i) dst[i] = w0 * s0[i];
      return;
    }
    if (taps == 2) {
      const float w0 = w[0], w1 = w[1];
      const float *__restrict s0 = src[0], *__restrict s1 = src[1];
      for (size_t i = 0; i < n; ++i) dst[i] = w0 * s0[i] + w1 * s1[i];
      return;
    }
    std::fill(dst, dst + n, 0.f);
    for (int d = 0; d < taps; ++d) Axpy(w[d], src[d], dst, n);
  }

  void FoldX(int x, int fx) {
    const AxisTable& X = t_.axis[0];
    const size_t w0 = size_t(x) * size_t(X.taps);
    const float* pa[kMaxTaps];
    const float* pb[kMaxTaps];
    for (int d = 0; d < X.taps; ++d) {
      pa[d] = Plane(fx + d, 0);
      pb[d] = kinds_ == 2 ? Plane(fx + d, 1) : nullptr;
    }
    Combine(&X.wc[w0], pa, X.taps, gc_.data(), plane_);
    if (cubic_) Combine(&X.wl[w0], pa, X.taps, gl_.data(), plane_);
    if (kinds_ == 2) Combine(&X.wl[w0], pb, X.taps, gb_.data(), plane_);
  }

  void FoldY() {
    const AxisTable& Y = t_.axis[1];
    const size_t sz = size_t(sz_);
    for (int y = 0; y < g_.count[1]; ++y) {
      const size_t w0 = size_t(y) * size_t(Y.taps);
      const int f = Y.first[size_t(y)];
      const float *rc[kMaxTaps], *rl[kMaxTaps], *rb[kMaxTaps];
      for (int d = 0; d < Y.taps; ++d) {
        const size_t row = size_t(f + d) * sz;
        rc[d] = &gc_[row];
        rl[d] = cubic_ ? &gl_[row] : nullptr;
        rb[d] = kinds_ == 2 ? &gb_[row] : nullptr;
      }
      // A degenerate axis (one tap) passes every channel through.
      const float one = 1.f;
      const float* wa = Y.taps == 1 ? &one : (cubic_ ? &Y.wa[w0] : &Y.wc[w0]);
      float* hc = &hc_[size_t(y) * sz];
      Combine(wa, rc, Y.taps, hc, sz);
      if (cubic_) {
        for (int d = 0; d < Y.taps; ++d) Axpy(Y.wb[w0 + d], rl[d], hc, sz);
        Combine(&Y.wl[w0], rl, Y.taps, &hl_[size_t(y) * sz], sz);
      }
      if (kinds_ == 2) Combine(&Y.wl[w0], rb, Y.taps, &hb_[size_t(y) * sz], sz);
    }
  }

  void FoldZ(float* out) {
    switch (t_.axis[2].taps) {
      case 1: return FoldZTaps<1>(out);
      case 2: return FoldZTaps<2>(out);
      default: return FoldZTaps<4>(out);
    }
  }

  // Per run of z samples that share a stencil: the nodes' channel values
  // are constants, the weights vary with z (vectorises).
  template <int kTaps>
  void FoldZTaps(float* __restrict out) {
    const AxisTable& Z = t_.axis[2];
    const size_t sz = size_t(sz_), nz = size_t(g_.count[2]);
    const float* __restrict za = Z.za.data();
    const float* __restrict zb = Z.zb.data();
    const float* __restrict zl = Z.zl.data();
    const bool with_l = cubic_ && kTaps > 1, with_b = kinds_ == 2;
    for (int y = 0; y < g_.count[1]; ++y) {
      const float* hc = &hc_[size_t(y) * sz];
      const float* hl = cubic_ ? &hl_[size_t(y) * sz] : nullptr;
      const float* hb = with_b ? &hb_[size_t(y) * sz] : nullptr;
      float* __restrict o = out + size_t(y) * nz;
      for (const AxisTable::Run& r : Z.runs) {
        float c[kTaps], l[kTaps], b[kTaps];
        for (int d = 0; d < kTaps; ++d) {
          c[d] = weight_ * hc[r.first + d];
          l[d] = with_l ? weight_ * hl[r.first + d] : 0.f;
          b[d] = with_b ? weight_ * hb[r.first + d] : 0.f;
        }
        // One pass per channel keeps each loop simple enough to vectorise.
        for (int z = r.begin; z < r.end; ++z) {
          float v = 0;
          for (int d = 0; d < kTaps; ++d) v += za[size_t(d) * nz + size_t(z)] * c[d];
          o[z] += v;
        }
        if (with_l)
          for (int z = r.begin; z < r.end; ++z) {
            float v = 0;
            for (int d = 0; d < kTaps; ++d) v += zb[size_t(d) * nz + size_t(z)] * l[d];
            o[z] += v;
          }
        if (with_b)
          for (int z = r.begin; z < r.end; ++z) {
            float v = 0;
            for (int d = 0; d < kTaps; ++d) v += zl[size_t(d) * nz + size_t(z)] * b[d];
            o[z] += v;
          }
      }
    }
  }

  const MeshTables& t_;
  const FieldGrid& g_;
  uint64_t key_;
  float weight_;
  bool cubic_;
  int sy_, sz_;
  size_t plane_;
  int kinds_ = 1, ring_ = 2;
  std::vector<float> planes_;
  std::vector<int> tags_;
  std::vector<float> gc_, gl_, gb_, hc_, hl_, hb_;
};

// The fallback for rotated meshes and mixing maps: the point evaluator.
void PointRow(const FractalField& f, size_t k, const FieldGrid& g, int x, float* out) {
  const float w = float(f.params().meshes[k].weight);
  for (int y = 0; y < g.count[1]; ++y)
    for (int z = 0; z < g.count[2]; ++z) {
      const double p[3] = {g.origin[0] + x * g.step[0], g.origin[1] + y * g.step[1],
                           g.origin[2] + z * g.step[2]};
      out[(size_t(x) * size_t(g.count[1]) + size_t(y)) * size_t(g.count[2]) + size_t(z)] +=
          w * float(f.EvalMesh(k, f.Map(p, g.time)));
    }
}

}  // namespace

absl::Status EvaluateFieldGrid(const FractalField& field, const FieldGrid& grid, float* out,
                               Interrupter* interrupter) {
  const int s = field.params().mapping.space_dims;
  for (int i = 0; i < 3; ++i) {
    if (grid.count[i] < 1) return absl::InvalidArgumentError("field grid: empty axis");
    if (i >= s && grid.count[i] != 1)
      return absl::InvalidArgumentError(
          absl::StrCat("field grid: axis ", i, " is beyond the field's ", s, " space axes"));
  }
  std::fill(out, out + grid.size(), 0.f);
  const size_t meshes = field.params().meshes.size();
  std::vector<MeshTables> tables(meshes);
  for (size_t k = 0; k < meshes; ++k) tables[k] = BuildTables(field, k, grid);

  Interrupter& intr = OrNull(interrupter);
  std::atomic<bool> stop{false};
  std::atomic<uint64_t> rows_done{0};
  const uint64_t total_rows = uint64_t(grid.count[0]) * meshes;
  // Slabs of x rows; each sample's sum runs over the meshes in order, so the
  // partition never changes a value.
  tbb::parallel_for(tbb::blocked_range<int>(0, grid.count[0], 4), [&](const auto& r) {
    // x outer, meshes inner: each x slice of the output stays in cache
    // while every mesh adds to it.
    std::vector<std::optional<SlabKernel>> kernels(meshes);
    for (size_t k = 0; k < meshes; ++k)
      if (tables[k].separable) kernels[k].emplace(field, k, tables[k], grid);
    for (int x = r.begin(); x < r.end(); ++x) {
      if (stop || intr.WasInterrupted(rows_done.load(), total_rows)) {
        stop = true;
        return;
      }
      for (size_t k = 0; k < meshes; ++k) {
        if (kernels[k])
          kernels[k]->Row(x, out);
        else
          PointRow(field, k, grid, x, out);
      }
      rows_done.fetch_add(meshes, std::memory_order_relaxed);
    }
  });
  if (stop) return absl::CancelledError("field evaluation interrupted");
  return absl::OkStatus();
}

}  // namespace nimbus
