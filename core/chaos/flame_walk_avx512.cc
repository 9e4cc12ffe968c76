// The flame kernel with AVX-512, eight lanes per register, SLEEF's 3.5-ulp
// vector functions (1-ulp exp and pow, which come in no other). Compiled
// without FMA contraction, so the arithmetic around the elementary
// functions rounds exactly as the scalar kernel's.
#include <immintrin.h>
#include <sleef.h>

#include <cstdint>

// The vector types carry may_alias, which GCC drops (harmlessly) when they
// are template arguments.
#pragma GCC diagnostic ignored "-Wignored-attributes"
// GCC 12's gather intrinsics start from an undefined register, which it
// reports as uninitialised; every lane is written.
#pragma GCC diagnostic ignored "-Wuninitialized"
#ifndef __clang__  // a GCC-only warning (the fuzz build uses clang)
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#endif

namespace nimbus::formulas {
namespace {

inline __m512d Sqrt(__m512d a) { return _mm512_sqrt_pd(a); }  // correctly rounded
inline __m512d Sin(__m512d a) { return Sleef_sind8_u35avx512f(a); }
inline __m512d Cos(__m512d a) { return Sleef_cosd8_u35avx512f(a); }
inline void SinCos(__m512d a, __m512d* s, __m512d* c) {
  const auto both = Sleef_sincosd8_u35avx512f(a);
  *s = both.x, *c = both.y;
}
inline __m512d Tan(__m512d a) { return Sleef_tand8_u35avx512f(a); }
inline __m512d Atan2(__m512d y, __m512d x) { return Sleef_atan2d8_u35avx512f(y, x); }
inline __m512d Exp(__m512d a) { return Sleef_expd8_u10avx512f(a); }
inline __m512d Pow(__m512d a, __m512d b) { return Sleef_powd8_u10avx512f(a, b); }
inline __m512d Cbrt(__m512d a) { return Sleef_cbrtd8_u35avx512f(a); }
inline __mmask8 IsNegative(__m512d a) {
  return _mm512_cmp_pd_mask(a, _mm512_setzero_pd(), _CMP_LT_OQ);
}
inline __mmask8 IsZero(__m512d a) { return _mm512_cmp_pd_mask(a, _mm512_setzero_pd(), _CMP_EQ_OQ); }
inline __mmask8 IsPositive(__m512d a) {
  return _mm512_cmp_pd_mask(a, _mm512_setzero_pd(), _CMP_GT_OQ);
}
inline __m512d Select(__mmask8 m, __m512d a, __m512d b) { return _mm512_mask_blend_pd(m, b, a); }
inline bool AllZero(__m512d a) { return IsZero(a) == 0xff; }

// Two registers as one number type, so a map evaluates sixteen walkers in
// one pass: the two halves' long chains (square roots, divisions, SLEEF's
// calls) are then in flight together instead of one register waiting on
// its own. Every operation is the eight-lane one on each half, so each
// lane computes the same bits.
struct D16 {
  __m512d lo, hi;
};
struct M16 {
  __mmask8 lo, hi;
};
template <class F>
inline D16 Both(const D16& a, F f) {
  return {f(a.lo), f(a.hi)};
}
template <class F>
inline D16 Both(const D16& a, const D16& b, F f) {
  return {f(a.lo, b.lo), f(a.hi, b.hi)};
}
inline D16 Wide(double a) { return {_mm512_set1_pd(a), _mm512_set1_pd(a)}; }
inline D16 operator+(const D16& a, const D16& b) {
  return Both(a, b, [](auto u, auto v) { return u + v; });
}
inline D16 operator-(const D16& a, const D16& b) {
  return Both(a, b, [](auto u, auto v) { return u - v; });
}
inline D16 operator*(const D16& a, const D16& b) {
  return Both(a, b, [](auto u, auto v) { return u * v; });
}
inline D16 operator/(const D16& a, const D16& b) {
  return Both(a, b, [](auto u, auto v) { return u / v; });
}
inline D16 operator+(const D16& a, double b) { return a + Wide(b); }
inline D16 operator-(const D16& a, double b) { return a - Wide(b); }
inline D16 operator*(const D16& a, double b) { return a * Wide(b); }
inline D16 operator/(const D16& a, double b) { return a / Wide(b); }
[[maybe_unused]] inline D16 operator+(double a, const D16& b) { return Wide(a) + b; }
inline D16 operator-(double a, const D16& b) { return Wide(a) - b; }
inline D16 operator*(double a, const D16& b) { return Wide(a) * b; }
inline D16 operator/(double a, const D16& b) { return Wide(a) / b; }
inline D16 operator-(const D16& a) {
  return Both(a, [](auto u) { return -u; });
}
inline D16 Sqrt(const D16& a) {
  return Both(a, [](auto u) { return Sqrt(u); });
}
inline D16 Sin(const D16& a) {
  return Both(a, [](auto u) { return Sin(u); });
}
inline D16 Cos(const D16& a) {
  return Both(a, [](auto u) { return Cos(u); });
}
inline void SinCos(const D16& a, D16* s, D16* c) {
  SinCos(a.lo, &s->lo, &c->lo);
  SinCos(a.hi, &s->hi, &c->hi);
}
inline D16 Tan(const D16& a) {
  return Both(a, [](auto u) { return Tan(u); });
}
inline D16 Atan2(const D16& y, const D16& x) {
  return Both(y, x, [](auto u, auto v) { return Atan2(u, v); });
}
inline D16 Exp(const D16& a) {
  return Both(a, [](auto u) { return Exp(u); });
}
inline D16 Pow(const D16& a, const D16& b) {
  return Both(a, b, [](auto u, auto v) { return Pow(u, v); });
}
inline D16 Cbrt(const D16& a) {
  return Both(a, [](auto u) { return Cbrt(u); });
}
inline M16 IsNegative(const D16& a) { return {IsNegative(a.lo), IsNegative(a.hi)}; }
inline M16 IsZero(const D16& a) { return {IsZero(a.lo), IsZero(a.hi)}; }
inline M16 IsPositive(const D16& a) { return {IsPositive(a.lo), IsPositive(a.hi)}; }
inline D16 Select(const M16& m, const D16& a, const D16& b) {
  return {Select(m.lo, a.lo, b.lo), Select(m.hi, a.hi, b.hi)};
}
inline bool AllZero(const D16& a) { return AllZero(a.lo) && AllZero(a.hi); }

}  // namespace
}  // namespace nimbus::formulas

#include "core/chaos/flame_walk_kernel.h"
#include "core/chaos/xoshiro_avx512.h"

namespace nimbus::flame {
namespace {

struct Avx512Isa {
  using T = __m512d;
  static constexpr int kWidth = 8;
  static constexpr bool kStaged = true;
  static __m512d Load(const double* p) { return _mm512_load_pd(p); }
  static void Store(double* p, __m512d v) { _mm512_store_pd(p, v); }
  static __m256i Index(const int32_t* lanes) {
    return _mm256_loadu_si256(reinterpret_cast<const __m256i*>(lanes));
  }
  // With few maps, each map's walkers are compressed out of 16-lane
  // registers in walker order; else the counting sort.
  static void SortByMap(uint32_t maps, Walkers& w, int n) {
    if (maps > 8) return SortByMapScalar(maps, w, n);
    const __m512i iota = _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
    uint32_t at = 0;
    for (uint32_t m = 0; m < maps; ++m) {
      w.group[m] = at;
      const __m512i want = _mm512_set1_epi32(int(m));
      for (int k = 0; k < n; k += 16) {
        const __mmask16 is = n - k >= 16 ? _mm512_cmpeq_epi32_mask(
                                               _mm512_loadu_si512(w.map + k), want)
                                         : _mm512_mask_cmpeq_epi32_mask(
                                               __mmask16((1u << (n - k)) - 1),
                                               _mm512_loadu_si512(w.map + k), want);
        _mm512_mask_compressstoreu_epi32(w.order + at, is,
                                         _mm512_add_epi32(iota, _mm512_set1_epi32(k)));
        at += uint32_t(__builtin_popcount(is));
      }
    }
    w.group[maps] = at;
  }
  static __m512d Gather(const double* base, __m256i i) { return _mm512_i32gather_pd(i, base, 8); }
  static void Scatter(double* base, __m256i i, __m512d v) { _mm512_i32scatter_pd(base, i, v, 8); }
  static __m512i GatherWord(const uint64_t* base, __m256i i) {
    return _mm512_i32gather_epi64(i, base, 8);
  }
  static __m512i LoadWord(const uint64_t* p) { return _mm512_loadu_si512(p); }
  // The lanes of walkers [k, k + 8) that took map m.
  static __mmask8 OfMap(const Walkers& w, int k, uint32_t m) {
    const __m512i maps = _mm512_castsi256_si512(
        _mm256_load_si256(reinterpret_cast<const __m256i*>(w.map + k)));
    return __mmask8(_mm512_mask_cmpeq_epi32_mask(0xff, maps, _mm512_set1_epi32(int(m))));
  }
  // Each map's walkers compressed, in walker order, into a run of the
  // staging arrays (register compresses and whole-register stores: a
  // compress straight to memory is slow on some CPUs), each run starting on
  // a register boundary and padded with its last walker, as MapsByIndex
  // pads.
  static void Stage(const MapTables& t, Walkers& w, int n, bool planar) {
    uint32_t at = 0;
    for (uint32_t m = 0; m < t.num_maps; ++m) {
      w.stage_begin[m] = at;
      const uint32_t words = t.words[m];
      int tail = -1;  // the last register with walkers of map m
      for (int k = 0; k < n; k += kWidth) {
        const __mmask8 is = OfMap(w, k, m);
        if (is == 0) continue;
        _mm512_storeu_pd(w.sx + at, _mm512_maskz_compress_pd(is, _mm512_load_pd(w.x + k)));
        _mm512_storeu_pd(w.sy + at, _mm512_maskz_compress_pd(is, _mm512_load_pd(w.y + k)));
        if (!planar)
          _mm512_storeu_pd(w.sz + at, _mm512_maskz_compress_pd(is, _mm512_load_pd(w.z + k)));
        for (uint32_t c = 0; c < words; ++c) {
          const __m512i word = _mm512_loadu_si512(w.words + size_t(c + 1) * kMaxWalkers + k);
          _mm512_storeu_si512(w.sw[c] + at, _mm512_maskz_compress_epi64(is, word));
        }
        at += uint32_t(__builtin_popcount(is));
        tail = k;
      }
      w.stage_end[m] = at;
      if (at % kWidth != 0) Pad(w, tail, m, words, planar);
      at = (at + kWidth - 1) / kWidth * kWidth;
    }
  }
  // Fills the lanes of a run's last register past its end with its last
  // walker, taken from walker register `k` (reading back the staging
  // arrays just stored would wait for the stores).
  static void Pad(Walkers& w, int k, uint32_t m, uint32_t words, bool planar) {
    const __mmask8 is = OfMap(w, k, m);
    const uint32_t end = w.stage_end[m];
    const __mmask8 pad = __mmask8(0xff << (end % kWidth));
    const __m512i last = _mm512_set1_epi64(31 - __builtin_clz(is));
    auto fill = [&](double* run, const double* from) {
      _mm512_mask_storeu_pd(run + end / kWidth * kWidth, pad,
                            _mm512_permutexvar_pd(last, _mm512_load_pd(from + k)));
    };
    fill(w.sx, w.x), fill(w.sy, w.y);
    if (!planar) fill(w.sz, w.z);
    for (uint32_t c = 0; c < words; ++c) {
      const __m512i word = _mm512_loadu_si512(w.words + size_t(c + 1) * kMaxWalkers + k);
      _mm512_mask_storeu_epi64(w.sw[c] + end / kWidth * kWidth, pad,
                               _mm512_permutexvar_epi64(last, word));
    }
  }
  // Stage's inverse: each register of walkers expanded from the runs.
  // A planar program's z is +0 for every walker.
  static void Unstage(uint32_t maps, Walkers& w, int n, bool planar) {
    uint32_t at[kStageMaps];
    for (uint32_t m = 0; m < maps; ++m) at[m] = w.stage_begin[m];
    for (int k = 0; k < n; k += kWidth) {
      __m512d x = _mm512_setzero_pd(), y = x, z = x;
      for (uint32_t m = 0; m < maps; ++m) {
        const __mmask8 is = OfMap(w, k, m);
        x = _mm512_mask_expand_pd(x, is, _mm512_loadu_pd(w.sx + at[m]));
        y = _mm512_mask_expand_pd(y, is, _mm512_loadu_pd(w.sy + at[m]));
        if (!planar) z = _mm512_mask_expand_pd(z, is, _mm512_loadu_pd(w.sz + at[m]));
        at[m] += uint32_t(__builtin_popcount(is));
      }
      _mm512_store_pd(w.x + k, x), _mm512_store_pd(w.y + k, y), _mm512_store_pd(w.z + k, z);
    }
  }
  // Exact: the 53 bits convert without rounding, as the scalar Rng's do.
  static __m512d Uniform(__m512i w) {
    return _mm512_mul_pd(_mm512_cvtepu64_pd(_mm512_srli_epi64(w, 11)), _mm512_set1_pd(0x1.0p-53));
  }
  static __mmask8 Bit(__m512i w) { return _mm512_movepi64_mask(w); }
  static __m512d Zero() { return _mm512_setzero_pd(); }
  // The per-map tables a round reads, looked up for eight walkers' maps:
  // with at most eight maps each table sits in one register and a permute
  // looks it up (gathers cost far more), else a gather.
  struct Tables {
    explicit Tables(const Program& prog) : p(prog), small(prog.maps.num_maps <= 8) {
      if (!small) return;
      const __mmask16 in = __mmask16((1u << p.maps.num_maps) - 1);
      threshold =
          _mm512_cvtepu32_epi64(_mm512_castsi512_si256(_mm512_maskz_loadu_epi32(in, p.threshold)));
      alias = _mm512_cvtepu32_epi64(_mm512_castsi512_si256(_mm512_maskz_loadu_epi32(in, p.alias)));
      color = _mm512_maskz_loadu_pd(__mmask8(in), p.maps.color);
    }
    __m512i Threshold(__m512i i) const {
      return small ? _mm512_permutexvar_epi64(i, threshold) : Gather32(p.threshold, i);
    }
    __m512i Alias(__m512i i) const {
      return small ? _mm512_permutexvar_epi64(i, alias) : Gather32(p.alias, i);
    }
    __m512d Color(__m512i i) const {
      return small ? _mm512_permutexvar_pd(i, color) : _mm512_i64gather_pd(i, p.maps.color, 8);
    }
    static __m512i Gather32(const uint32_t* table, __m512i i) {
      return _mm512_cvtepu32_epi64(_mm512_i64gather_epi32(i, table, 4));
    }
    const Program& p;
    const bool small;
    __m512i threshold = _mm512_setzero_si512(), alias = threshold;
    __m512d color = _mm512_setzero_pd();
  };
  // One pass over the walkers does what the scalar kernel's DrawWords,
  // PickMapsScalar and Recolor do in three: Rng::Next for each of the
  // step's words, AliasTable::Sample on word 0 (the 32 x 32-bit product
  // picks the column, the low half of the word decides between it and its
  // alias), then the colour. Each register's first word, maps and colours
  // stay in registers between them, and small tables are loaded once.
  static void DrawPickRecolor(const Program& p, Walkers& w, int n) {
    const Tables t(p);
    const __m512i num = _mm512_set1_epi64(p.maps.num_maps), low = _mm512_set1_epi64(0xffffffff);
    const __m512d inv_maps = _mm512_set1_pd(p.inv_maps);
    for (int k = 0; k < n; k += kWidth) {
      __m512i s0 = _mm512_load_si512(w.s0 + k), s1 = _mm512_load_si512(w.s1 + k);
      __m512i s2 = _mm512_load_si512(w.s2 + k), s3 = _mm512_load_si512(w.s3 + k);
      const __m512i r = simd::XoshiroNext(s0, s1, s2, s3);
      _mm512_storeu_si512(w.words + k, r);
      for (uint32_t c = 1; c < p.words; ++c)
        _mm512_storeu_si512(w.words + size_t(c) * kMaxWalkers + k,
                            simd::XoshiroNext(s0, s1, s2, s3));
      _mm512_store_si512(w.s0 + k, s0), _mm512_store_si512(w.s1 + k, s1);
      _mm512_store_si512(w.s2 + k, s2), _mm512_store_si512(w.s3 + k, s3);
      const __m512i i = _mm512_srli_epi64(_mm512_mul_epu32(_mm512_srli_epi64(r, 32), num), 32);
      const __mmask8 keep = _mm512_cmplt_epu64_mask(_mm512_and_si512(r, low), t.Threshold(i));
      const __m512i m = _mm512_mask_blend_epi64(keep, t.Alias(i), i);
      _mm256_storeu_si256(reinterpret_cast<__m256i*>(w.map + k), _mm512_cvtepi64_epi32(m));
      if (p.color_mode == 0) continue;
      const __m512d addr = (_mm512_cvtepi64_pd(m) + _mm512_load_pd(w.addr + k)) * inv_maps;
      _mm512_store_pd(w.addr + k, addr);
      const __m512d target = p.color_mode == 2 ? addr : t.Color(m);
      const __m512d col = _mm512_load_pd(w.col + k);
      _mm512_store_pd(w.col + k, col + p.blend * (target - col));
    }
  }
  // Sixteen lanes of a staged run at once (formulas::D16), for MapsStaged.
  struct Pair {
    using T = formulas::D16;
    struct Words {
      __m512i lo, hi;
    };
    static constexpr int kWidth = 16;
    static T Load(const double* p) { return {_mm512_load_pd(p), _mm512_load_pd(p + 8)}; }
    static void Store(double* p, const T& v) {
      _mm512_store_pd(p, v.lo), _mm512_store_pd(p + 8, v.hi);
    }
    static Words LoadWord(const uint64_t* p) {
      return {_mm512_loadu_si512(p), _mm512_loadu_si512(p + 8)};
    }
    static T Uniform(const Words& w) {
      return {Avx512Isa::Uniform(w.lo), Avx512Isa::Uniform(w.hi)};
    }
    static formulas::M16 Bit(const Words& w) {
      return {Avx512Isa::Bit(w.lo), Avx512Isa::Bit(w.hi)};
    }
    static T Zero() { return {_mm512_setzero_pd(), _mm512_setzero_pd()}; }
  };
};

}  // namespace

void RoundAvx512(const Program& p, Walkers& w, int n) { RoundWith<Avx512Isa>(p, w, n); }

}  // namespace nimbus::flame
