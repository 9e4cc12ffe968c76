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

}  // namespace nimbus::testing
