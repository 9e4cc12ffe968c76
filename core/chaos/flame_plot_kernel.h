// @brief The body of PlotAvx2 and PlotAvx512, written once over an
// instruction-set description `Isa` and included by each kernel's
// translation unit. Isa has: D (doubles), I (64-bit integers), M (a lane
// mask), kWidth; Set(double), Zero(), Abs, Add/Sub/Mul/Div; Load(const
// double*); Ge/Lt/Gt(D, D) giving masks, And(M, M), All() and Bits(M) (bit
// k is lane k); Select(M, if_false, if_true); TruncSigned and TruncUnsigned
// (toward zero into 64-bit lanes, exact for values in [0, 2^31), the only
// ones whose keys are kept);
// Splat(uint64_t), AndI, OrI, AddI, MulLo32 (the low 32 bits of each lane,
// multiplied to 64), ShrBy(I, count), Shl<k> and Shr<k>; StoreKeys.
// Every operation is one correctly rounded add, multiply or divide in the
// scalar kernel's order (the files are built without FMA contraction), so
// the keys are the scalar kernel's bit for bit.
#pragma once

#include <algorithm>
#include <cstdint>

#include "core/chaos/flame_plot.h"

namespace nimbus::flame {
namespace {

template <class Isa>
struct PlotKernel {
  using D = typename Isa::D;
  using I = typename Isa::I;
  using M = typename Isa::M;

  // |v| < inf: false for infinities and NaN, as std::isfinite.
  static M Finite(D v) { return Isa::Lt(Isa::Abs(v), Isa::Set(__builtin_inf())); }
  // lo <= v < hi, false for NaN.
  static M InRange(D v, double lo, double hi) {
    return Isa::And(Isa::Ge(v, Isa::Set(lo)), Isa::Lt(v, Isa::Set(hi)));
  }
  // One row of view * q in Affine3::Apply's order.
  static D Row(const double* r, D x, D y, D z) {
    using S = Isa;
    return S::Add(S::Add(S::Add(S::Mul(S::Set(r[0]), x), S::Mul(S::Set(r[1]), y)),
                         S::Mul(S::Set(r[2]), z)),
                  S::Set(r[3]));
  }

  // The lattice coordinates of kWidth points and the lanes that land.
  static M Project(const PlotTarget& t, D x, D y, D z, D f[3]) {
    using S = Isa;
    M in = S::All();
    if (t.kind == PlotTarget::kGrid) {
      const D p[3] = {x, y, z};
      for (int a = 0; a < 3; ++a)
        f[a] = S::Mul(S::Sub(p[a], S::Set(t.min[a])), S::Set(t.inv_voxel[a]));
    } else if (t.axis_aligned) {
      f[0] = S::Add(S::Mul(S::Set(t.view[0]), x), S::Set(t.view[3]));
      f[1] = S::Add(S::Mul(S::Set(t.view[5]), y), S::Set(t.view[7]));
      f[2] = S::Zero();
      in = InRange(S::Add(S::Mul(S::Set(t.view[10]), z), S::Set(t.view[11])), 0, 1);
    } else {
      D cx = Row(t.view, x, y, z), cy = Row(t.view + 4, x, y, z);
      const D cz = Row(t.view + 8, x, y, z);
      if (t.kind == PlotTarget::kPerspective) {
        in = S::Gt(cz, S::Set(t.near));
        cx = S::Add(S::Set(t.cx), S::Div(S::Mul(S::Set(t.focal), cx), cz));
        cy = S::Sub(S::Set(t.cy), S::Div(S::Mul(S::Set(t.focal), cy), cz));
      } else {
        in = InRange(cz, 0, 1);
      }
      f[0] = cx, f[1] = cy, f[2] = S::Zero();
    }
    return S::And(S::And(in, InRange(f[0], 0, t.res[0])),
                  S::And(InRange(f[1], 0, t.res[1]), InRange(f[2], 0, t.res[2])));
  }

  // CountGrid::Key of the truncated coordinates.
  static I Key(const PlotTarget& t, const D f[3]) {
    using S = Isa;
    const I x = S::TruncSigned(f[0]), y = S::TruncSigned(f[1]), z = S::TruncSigned(f[2]);
    const I sy = S::ShrBy(y, t.fold_shift);
    const I sz = S::AddI(z, S::AndI(y, S::Splat(t.fold_mask)));
    I tile = S::AddI(S::MulLo32(S::template Shr<5>(x), S::Splat(t.tiles_y)),
                     S::template Shr<5>(sy));
    tile = S::AddI(S::MulLo32(tile, S::Splat(t.tiles_z)), S::template Shr<5>(sz));
    // LocalOffset: leaf (lx >> 3, ly >> 3, lz >> 3) at bits 13, 11, 9, then
    // (lx & 7, ly & 7, lz & 7) at bits 6, 3, 0.
    const I hi3 = S::Splat(0x18), lo3 = S::Splat(7);
    I off = S::template Shl<10>(S::AndI(x, hi3));
    off = S::OrI(off, S::template Shl<8>(S::AndI(sy, hi3)));
    off = S::OrI(off, S::template Shl<6>(S::AndI(sz, hi3)));
    off = S::OrI(off, S::template Shl<6>(S::AndI(x, lo3)));
    off = S::OrI(off, S::template Shl<3>(S::AndI(sy, lo3)));
    off = S::OrI(off, S::AndI(sz, lo3));
    return S::OrI(S::template Shl<15>(tile), off);
  }

  // ColorBits: clamp to [0, 1], c * 65535 + 0.5 truncated, at bit 48.
  static I ColorBits(D col) {
    using S = Isa;
    D c = S::Select(S::Lt(col, S::Zero()), col, S::Zero());
    c = S::Select(S::Lt(S::Set(1), c), c, S::Set(1));
    const D scaled = S::Add(S::Mul(c, S::Set(65535.0)), S::Set(0.5));
    return S::template Shl<48>(S::TruncUnsigned(scaled));
  }

  static void Plot(const PlotTarget& t, const Walkers& w, bool final_map, int n, Plotted* out) {
    if (t.planar && !final_map)
      PlotAs<true>(t, w, false, n, out);
    else
      PlotAs<false>(t, w, final_map, n, out);
  }

  // kPlanar: z is +0 where x and y are finite (PlotTarget::planar), so a
  // walker is finite exactly when x and y are, and z's projection and
  // bounds are the same every time (the compiler lifts them).
  template <bool kPlanar>
  static void PlotAs(const PlotTarget& target, const Walkers& w, bool final_map, int n,
                     Plotted* out) {
    using S = Isa;
    // A copy the key stores cannot alias: stored through a vector type
    // that may alias anything, they made every round reload and convert
    // the target's numbers.
    const PlotTarget t = target;
    constexpr uint64_t kAll = (uint64_t{1} << S::kWidth) - 1;
    const double* px = final_map ? w.fx : w.x;
    const double* py = final_map ? w.fy : w.y;
    const double* pz = final_map ? w.fz : w.z;
    out->ClearMasks();
    for (int base = 0; base < n; base += 64) {  // mask word base / 64
      const int end = std::min(n, base + 64);
      uint64_t inside = 0, bad_walker = 0, bad_final = 0;
      for (int k = base; k < end; k += S::kWidth) {
        const M flat = S::And(Finite(S::Load(w.x + k)), Finite(S::Load(w.y + k)));
        const M walker = kPlanar ? flat : S::And(flat, Finite(S::Load(w.z + k)));
        const D x = S::Load(px + k), y = S::Load(py + k);
        const D z = kPlanar ? S::Zero() : S::Load(pz + k);
        // Without a final transform the point is the walker's own.
        const M point =
            final_map ? S::And(walker, S::And(S::And(Finite(x), Finite(y)), Finite(z))) : walker;
        D f[3];
        const M in = S::And(point, Project(t, x, y, z, f));
        I key = Key(t, f);
        if (t.color) key = S::OrI(key, ColorBits(S::Load(w.col + k)));
        S::StoreKeys(out->key + k, key);
        inside |= S::Bits(in) << (k - base);
        bad_walker |= (S::Bits(walker) ^ kAll) << (k - base);
        bad_final |= (S::Bits(walker) & ~S::Bits(point)) << (k - base);
      }
      out->inside[base / 64] = inside;
      out->bad_walker[base / 64] = bad_walker, out->bad_final[base / 64] = bad_final;
    }
  }
};

}  // namespace
}  // namespace nimbus::flame
