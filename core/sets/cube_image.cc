#include "core/sets/cube_image.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <cstdint>
#include <optional>

namespace nimbus {
namespace {

// Bits [b0, b1] of a word.
inline uint64_t BitRange(int b0, int b1) {
  return (~uint64_t{0} >> (63 - b1)) & (~uint64_t{0} << b0);
}

using V3 = std::array<int64_t, 3>;

// orient(p, q, r, v) = det[q - p, r - p, v - p] as n . v + d, with
// n = (q - p) x (r - p): zero on the plane of (p, q, r), its sign the side.
struct Plane {
  V3 n;
  int64_t d;
};
Plane PlaneOf(Int3 p, Int3 q, Int3 r) {
  const V3 u{q.x - p.x, q.y - p.y, q.z - p.z}, w{r.x - p.x, r.y - p.y, r.z - p.z};
  const V3 n{u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0]};
  return {n, -(n[0] * p.x + n[1] * p.y + n[2] * p.z)};
}

int64_t Eval(const Plane& p, int64_t x, int64_t y, int64_t z) {
  return p.n[0] * x + p.n[1] * y + p.n[2] * z + p.d;
}

// The six tetrahedra {0, a, b, 7} of a cube image share their faces: the
// planes through the diagonal (0, c, 7), and the faces (0, a, b) and
// (a, b, 7). Each is computed once (18 planes instead of 24). The volume
// orient(0, a, b, 7) gives a tetrahedron's orientation, and the
// antisymmetry of the determinant the sign each face's determinant (v in
// place of the opposite corner) takes relative to it: + for (0, a, b) and
// (0, b, 7), - for (a, b, 7) and (0, a, 7). A voxel is inside when all four
// have the volume's sign or vanish, which is the orientation test of each
// corner. Flat tetrahedra are dropped: the edge bridges cover them.
struct CubeTets {
  struct Tet {
    int a, b;
    int64_t sign;  // of the volume
    Plane low, high;  // orient(0, a, b, v), orient(a, b, 7, v)
  };
  Plane diag[7];  // orient(0, c, 7, v) for c = 1..6
  Tet tets[6];
  int count = 0;

  explicit CubeTets(const Int3 (&img)[8]) {
    static constexpr int kAB[6][2] = {{1, 3}, {1, 5}, {2, 3}, {2, 6}, {4, 5}, {4, 6}};
    for (int c = 1; c < 7; ++c) diag[c] = PlaneOf(img[0], img[c], img[7]);
    const Int3 top = img[7];
    for (const auto& [a, b] : kAB) {
      const Plane low = PlaneOf(img[0], img[a], img[b]);
      const int64_t vol = Eval(low, top.x, top.y, top.z);
      if (vol != 0) tets[count++] = {a, b, vol > 0 ? 1 : -1, low, PlaneOf(img[7], img[a], img[b])};
    }
  }
  // The diagonal planes first, once for all six: they place v in the
  // wedges of few tetrahedra, and only those test their other two faces.
  bool Contains(int64_t x, int64_t y, int64_t z) const {
    int64_t side[7];
    for (int c = 1; c < 7; ++c) side[c] = Eval(diag[c], x, y, z);
    for (int i = 0; i < count; ++i) {
      const Tet& t = tets[i];
      if (t.sign * side[t.b] < 0 || t.sign * side[t.a] > 0) continue;
      if (t.sign * Eval(t.low, x, y, z) < 0 || t.sign * Eval(t.high, x, y, z) > 0) continue;
      return true;
    }
    return false;
  }
};

// A necessary test for the hull of the eight images, far cheaper than the
// tetrahedra: a voxel on the side x = min x of the images' box is a convex
// combination only of images with that x (any other would pull its x up),
// and likewise for every side it touches; so it must lie in the box of the
// images on all its sides, and there must be some. Most voxels a fill tests
// are such box corners and edges, left open by images that meet only in
// part (the tetrahedra lie in the hull, so rejecting these is exact).
class HullFilter {
 public:
  explicit HullFilter(const Int3 (&img)[8]) : img_(img) {
    lo_[0] = hi_[0] = img[0].x;
    lo_[1] = hi_[1] = img[0].y;
    lo_[2] = hi_[2] = img[0].z;
    for (int c = 1; c < 8; ++c) {
      const int v[3] = {img[c].x, img[c].y, img[c].z};
      for (int a = 0; a < 3; ++a) {
        lo_[a] = std::min(lo_[a], v[a]);
        hi_[a] = std::max(hi_[a], v[a]);
      }
    }
    for (int c = 0; c < 8; ++c) {
      const int v[3] = {img[c].x, img[c].y, img[c].z};
      for (int a = 0; a < 3; ++a) {
        at_lo_[a] |= unsigned(v[a] == lo_[a]) << c;
        at_hi_[a] |= unsigned(v[a] == hi_[a]) << c;
      }
    }
  }
  // Images on the sides that coordinate v of axis a touches (all of them
  // when it touches none): the y and z parts are shared by a whole row.
  unsigned Side(int a, int v) const {
    return (v == lo_[a] ? at_lo_[a] : 0xffu) & (v == hi_[a] ? at_hi_[a] : 0xffu);
  }
  // `on` is Side(0, x) & Side(1, y) & Side(2, z).
  bool MayContain(unsigned on, int x, int y, int z) const {
    if (on == 0xffu) return true;  // inside the box: only the full test decides
    if (on == 0) return false;
    Int3 lo{1 << 30, 1 << 30, 1 << 30}, hi{-(1 << 30), -(1 << 30), -(1 << 30)};
    for (; on; on &= on - 1) {
      const Int3& p = img_[std::countr_zero(on)];
      lo = {std::min(lo.x, p.x), std::min(lo.y, p.y), std::min(lo.z, p.z)};
      hi = {std::max(hi.x, p.x), std::max(hi.y, p.y), std::max(hi.z, p.z)};
    }
    return x >= lo.x && x <= hi.x && y >= lo.y && y <= hi.y && z >= lo.z && z <= hi.z;
  }

 private:
  const Int3 (&img_)[8];
  int lo_[3], hi_[3];
  unsigned at_lo_[3] = {0, 0, 0}, at_hi_[3] = {0, 0, 0};
};

}  // namespace

bool BoxFilled(const VoxelSet& out, const VoxelBox& box) {
  for (int z = box.min.z; z <= box.max.z; ++z)
    for (int y = box.min.y; y <= box.max.y; ++y) {
      // The words are updated through atomic_ref by other threads.
      uint64_t* row = const_cast<uint64_t*>(out.Row(y, z));
      for (int w = box.min.x >> 6; w <= box.max.x >> 6; ++w) {
        const uint64_t want = BitRange(w == box.min.x >> 6 ? box.min.x & 63 : 0,
                                       w == box.max.x >> 6 ? box.max.x & 63 : 63);
        std::atomic_ref<uint64_t> word(row[w]);
        if ((word.load(std::memory_order_relaxed) & want) != want) return false;
      }
    }
  return true;
}

// One pass over the box for all six tetrahedra (not one per tetrahedron
// over its own box): each row word is read once and only its missing bits
// are tested, since most are set already (the images of neighbouring cubes
// overlap); the HullFilter drops most of the rest, the planes are prepared
// on the first missing bit it lets through, and `worth`
// is asked on the first bit the fill would add (most boxes' missing bits
// lie outside the tetrahedra, and then the check is never needed).
void FillCubeImage(const Int3 (&img)[8], const VoxelBox& box, VoxelSet& out,
                   absl::FunctionRef<bool()> worth) {
  std::optional<CubeTets> tets;
  const HullFilter hull(img);
  bool asked = false;
  for (int z = box.min.z; z <= box.max.z; ++z)
    for (int y = box.min.y; y <= box.max.y; ++y) {
      const unsigned on_yz = hull.Side(1, y) & hull.Side(2, z);
      if (!on_yz) continue;  // no image on both sides this row touches
      uint64_t* row = out.MutableRow(y, z);
      for (int w = box.min.x >> 6; w <= box.max.x >> 6; ++w) {
        std::atomic_ref<uint64_t> word(row[w]);
        const uint64_t want = BitRange(w == box.min.x >> 6 ? box.min.x & 63 : 0,
                                       w == box.max.x >> 6 ? box.max.x & 63 : 63);
        uint64_t missing = want & ~word.load(std::memory_order_relaxed), add = 0;
        for (; missing; missing &= missing - 1) {
          const int b = std::countr_zero(missing), x = (w << 6) + b;
          if (!hull.MayContain(on_yz & hull.Side(0, x), x, y, z)) continue;
          if (!tets) tets.emplace(img);  // planes only once a voxel may be inside
          if (!tets->Contains(x, y, z)) continue;
          if (!asked && !(asked = true, worth())) return;
          add |= uint64_t{1} << b;
        }
        if (add) word.fetch_or(add, std::memory_order_relaxed);
      }
    }
}

}  // namespace nimbus
