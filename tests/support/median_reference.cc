#include "tests/support/median_reference.h"

#include <algorithm>

#include "absl/strings/str_cat.h"

namespace nimbus::testing {
namespace {

// Halfway along one axis; odd sums lie on a face and go the way `up` says.
int Half(int a, int b, bool up) {
  const int s = a + b;
  if (s % 2 == 0) return s / 2;
  return up ? (s + 1) / 2 : (s - 1) / 2;
}

Int3 Halfway(Int3 a, Int3 b, unsigned round_up) {
  return {Half(a.x, b.x, round_up & 1), Half(a.y, b.y, round_up & 2),
          Half(a.z, b.z, round_up & 4)};
}

double WorldDistance2(Int3 a, Int3 b, Vec3 h) {
  const double dx = (a.x - b.x) * h.x, dy = (a.y - b.y) * h.y, dz = (a.z - b.z) * h.z;
  return dx * dx + dy * dy + dz * dz;
}

std::vector<Int3> Members(const VoxelSet& s) {
  std::vector<Int3> out;
  s.ForEach([&](int x, int y, int z) { out.push_back({x, y, z}); });
  return out;
}

std::string Str(Int3 v) {
  return absl::StrCat("(", v.x, ",", v.y, ",", v.z, ")");
}

// Adds D_from(to) to `ref`: every voxel of `from` outside `to` moves halfway
// to its nearest voxel(s) of `to`. Distances within a relative 1e-9 of the
// best count as ties, so the oracle never guesses how a tie is broken.
void AddSide(const VoxelSet& from, const VoxelSet& to, Vec3 h, unsigned round_up,
             ReferenceMedian& ref) {
  const std::vector<Int3> targets = Members(to);
  for (const Int3& a : Members(from)) {
    if (to.Get(a)) {
      ref.certain.Set(a);
      continue;
    }
    double best = 1e300;
    for (const Int3& b : targets) best = std::min(best, WorldDistance2(a, b, h));
    std::vector<Int3> images;
    for (const Int3& b : targets) {
      if (WorldDistance2(a, b, h) > best * (1 + 1e-9)) continue;
      const Int3 m = Halfway(a, b, round_up);
      if (std::find(images.begin(), images.end(), m) == images.end()) images.push_back(m);
    }
    if (images.size() == 1)
      ref.certain.Set(images[0]);
    else
      ref.alternatives.push_back(std::move(images));
  }
}

}  // namespace

ReferenceMedian BruteForceMedian(const VoxelSet& a, const VoxelSet& b, Vec3 h, unsigned round_up,
                                 bool both_sides) {
  ReferenceMedian ref{VoxelSet(a.resolution()), {}};
  AddSide(a, b, h, round_up, ref);
  if (both_sides) AddSide(b, a, h, round_up, ref);
  return ref;
}

bool Admits(const ReferenceMedian& ref, const VoxelSet& got, std::string* why) {
  auto fail = [&](const std::string& what) {
    if (why) *why = what;
    return false;
  };
  if (!(got.resolution() == ref.certain.resolution())) return fail("resolution differs");
  for (const Int3& v : Members(ref.certain))
    if (!got.Get(v)) return fail("missing " + Str(v));
  for (const auto& alt : ref.alternatives)
    if (std::none_of(alt.begin(), alt.end(), [&](Int3 v) { return got.Get(v); }))
      return fail("no image of a tied voxel, e.g. " + Str(alt[0]));
  for (const Int3& v : Members(got)) {
    if (ref.certain.Get(v)) continue;
    const bool tied = std::any_of(ref.alternatives.begin(), ref.alternatives.end(),
                                  [&](const auto& alt) {
                                    return std::find(alt.begin(), alt.end(), v) != alt.end();
                                  });
    if (!tied) return fail("unexpected " + Str(v));
  }
  return true;
}

std::vector<unsigned> AdmittingRoundings(const VoxelSet& a, const VoxelSet& b, Vec3 h,
                                         bool both_sides, const VoxelSet& got) {
  std::vector<unsigned> out;
  for (unsigned r = 0; r < 8; ++r)
    if (Admits(BruteForceMedian(a, b, h, r, both_sides), got)) out.push_back(r);
  return out;
}

VoxelSet VoxelSetOf(Int3 resolution, const std::vector<Int3>& voxels) {
  VoxelSet s(resolution);
  for (const Int3& v : voxels) s.Set(v);
  return s;
}

namespace {

// det[b - a, c - a, d - a]: positive when d lies on the left of (a, b, c).
int64_t Orientation(Int3 a, Int3 b, Int3 c, Int3 d) {
  const int64_t u[3] = {b.x - a.x, b.y - a.y, b.z - a.z};
  const int64_t v[3] = {c.x - a.x, c.y - a.y, c.z - a.z};
  const int64_t w[3] = {d.x - a.x, d.y - a.y, d.z - a.z};
  return u[0] * (v[1] * w[2] - v[2] * w[1]) - u[1] * (v[0] * w[2] - v[2] * w[0]) +
         u[2] * (v[0] * w[1] - v[1] * w[0]);
}

// Closed tetrahedron test: replacing each corner by q keeps the volume's
// sign or makes it zero.
bool InTetrahedron(const Int3 (&t)[4], Int3 q) {
  const int64_t vol = Orientation(t[0], t[1], t[2], t[3]);
  if (vol == 0) return false;
  for (int i = 0; i < 4; ++i) {
    Int3 s[4] = {t[0], t[1], t[2], t[3]};
    s[i] = q;
    const int64_t o = Orientation(s[0], s[1], s[2], s[3]);
    if (vol > 0 ? o < 0 : o > 0) return false;
  }
  return true;
}

}  // namespace

VoxelSet BruteForceCubeImage(const Int3 (&img)[8], const VoxelBox& box, Int3 resolution) {
  static constexpr int kTets[6][4] = {{0, 1, 3, 7}, {0, 1, 5, 7}, {0, 2, 3, 7},
                                      {0, 2, 6, 7}, {0, 4, 5, 7}, {0, 4, 6, 7}};
  VoxelSet out(resolution);
  for (int z = box.min.z; z <= box.max.z; ++z)
    for (int y = box.min.y; y <= box.max.y; ++y)
      for (int x = box.min.x; x <= box.max.x; ++x)
        for (const auto& k : kTets) {
          const Int3 t[4] = {img[k[0]], img[k[1]], img[k[2]], img[k[3]]};
          if (InTetrahedron(t, {x, y, z})) {
            out.Set(x, y, z);
            break;
          }
        }
  return out;
}

}  // namespace nimbus::testing
