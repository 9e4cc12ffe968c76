#include "core/grid/voxel_set.h"

#include <algorithm>
#include <cassert>

#include "absl/strings/str_cat.h"
#include "core/base/status_macros.h"

namespace nimbus {

VoxelBox VoxelBox::Hull(const VoxelBox& a, const VoxelBox& b) {
  return {{std::min(a.min.x, b.min.x), std::min(a.min.y, b.min.y), std::min(a.min.z, b.min.z)},
          {std::max(a.max.x, b.max.x), std::max(a.max.y, b.max.y), std::max(a.max.z, b.max.z)}};
}

absl::Status ValidateSetResolution(Int3 r) {
  for (int a = 0; a < 3; ++a) {
    if (r[a] < 1 || r[a] > VoxelSet::kMaxResolution) {
      return absl::InvalidArgumentError(absl::StrCat("voxel set resolution ", r.x, "x", r.y, "x",
                                                     r.z, " is outside 1..",
                                                     VoxelSet::kMaxResolution, " per axis"));
    }
  }
  return absl::OkStatus();
}

absl::Status ValidateSetFrame(const GridFrame& frame) {
  NIMBUS_RETURN_IF_ERROR(ValidateSetResolution(frame.resolution));
  const Vec3 size = frame.bounds.Size();
  if (!IsFinite(frame.bounds.min) || !IsFinite(frame.bounds.max) || !(size.x > 0) ||
      !(size.y > 0) || !(size.z > 0)) {
    return absl::InvalidArgumentError("grid frame bounds must be finite with positive size");
  }
  return absl::OkStatus();
}

VoxelSet::VoxelSet(Int3 resolution)
    : res_(resolution),
      words_per_row_((resolution.x + 63) / 64),
      words_(size_t(resolution.y) * resolution.z * words_per_row_, 0) {
  assert(ValidateSetResolution(resolution).ok());
}

void VoxelSet::SetSpan(int x0, int x1, int y, int z) {
  if (x0 > x1) return;
  uint64_t* row = MutableRow(y, z);
  const int w0 = x0 >> 6, w1 = x1 >> 6;
  const uint64_t first = ~uint64_t{0} << (x0 & 63);
  const uint64_t last = ~uint64_t{0} >> (63 - (x1 & 63));
  if (w0 == w1) {
    row[w0] |= first & last;
    return;
  }
  row[w0] |= first;
  for (int w = w0 + 1; w < w1; ++w) row[w] = ~uint64_t{0};
  row[w1] |= last;
}

void VoxelSet::Clear() { std::fill(words_.begin(), words_.end(), 0); }

void VoxelSet::Fill() {
  for (int z = 0; z < res_.z; ++z)
    for (int y = 0; y < res_.y; ++y) SetSpan(0, res_.x - 1, y, z);
}

int64_t VoxelSet::Count() const {
  int64_t n = 0;
  for (uint64_t w : words_) n += std::popcount(w);
  return n;
}

bool VoxelSet::Empty() const {
  return std::all_of(words_.begin(), words_.end(), [](uint64_t w) { return w == 0; });
}

std::optional<VoxelBox> VoxelSet::BoundingBox() const {
  VoxelBox box{{res_.x, res_.y, res_.z}, {-1, -1, -1}};
  for (int z = 0; z < res_.z; ++z) {
    for (int y = 0; y < res_.y; ++y) {
      const uint64_t* row = Row(y, z);
      int first = -1, last = -1;
      for (int w = 0; w < words_per_row_; ++w) {
        if (!row[w]) continue;
        if (first < 0) first = (w << 6) + std::countr_zero(row[w]);
        last = (w << 6) + 63 - std::countl_zero(row[w]);
      }
      if (first < 0) continue;
      box.min = {std::min(box.min.x, first), std::min(box.min.y, y), std::min(box.min.z, z)};
      box.max = {std::max(box.max.x, last), std::max(box.max.y, y), std::max(box.max.z, z)};
    }
  }
  if (box.max.x < 0) return std::nullopt;
  return box;
}

VoxelSet& VoxelSet::operator|=(const VoxelSet& other) {
  assert(res_ == other.res_);
  for (size_t i = 0; i < words_.size(); ++i) words_[i] |= other.words_[i];
  return *this;
}

VoxelSet& VoxelSet::operator&=(const VoxelSet& other) {
  assert(res_ == other.res_);
  for (size_t i = 0; i < words_.size(); ++i) words_[i] &= other.words_[i];
  return *this;
}

VoxelSet& VoxelSet::operator-=(const VoxelSet& other) {
  assert(res_ == other.res_);
  for (size_t i = 0; i < words_.size(); ++i) words_[i] &= ~other.words_[i];
  return *this;
}

namespace {

// Bit x of the result is bit (x - s) of `row` (a left shift of the row by s
// bits, s may be negative); bits beyond `nx` are cleared.
void ShiftRowBits(const uint64_t* row, int words, int s, int nx, uint64_t* out) {
  const int ws = s >= 0 ? s >> 6 : -((-s + 63) >> 6);
  const int bs = s - ws * 64;  // 0..63
  for (int w = 0; w < words; ++w) {
    const int src = w - ws;
    const uint64_t lo = (src >= 0 && src < words) ? row[src] : 0;
    const uint64_t below = (src - 1 >= 0 && src - 1 < words) ? row[src - 1] : 0;
    out[w] = bs == 0 ? lo : (lo << bs) | (below >> (64 - bs));
  }
  if (nx & 63) out[words - 1] &= ~uint64_t{0} >> (64 - (nx & 63));
}

}  // namespace

VoxelSet ShiftSet(const VoxelSet& set, Int3 d) {
  const Int3 r = set.resolution();
  VoxelSet out(r);
  for (int z = 0; z < r.z; ++z) {
    const int sz = z - d.z;
    if (sz < 0 || sz >= r.z) continue;
    for (int y = 0; y < r.y; ++y) {
      const int sy = y - d.y;
      if (sy < 0 || sy >= r.y) continue;
      ShiftRowBits(set.Row(sy, sz), set.words_per_row(), d.x, r.x, out.MutableRow(y, z));
    }
  }
  return out;
}

VoxelSet BoundaryOf(const VoxelSet& set) {
  const Int3 r = set.resolution();
  const int words = set.words_per_row();
  VoxelSet out(r);
  std::vector<uint64_t> left(words), right(words);
  for (int z = 0; z < r.z; ++z) {
    for (int y = 0; y < r.y; ++y) {
      const uint64_t* row = set.Row(y, z);
      ShiftRowBits(row, words, 1, r.x, left.data());    // bit x = member x-1
      ShiftRowBits(row, words, -1, r.x, right.data());  // bit x = member x+1
      uint64_t* o = out.MutableRow(y, z);
      for (int w = 0; w < words; ++w) {
        uint64_t inner = row[w] & left[w] & right[w];
        inner &= y > 0 ? set.Row(y - 1, z)[w] : 0;
        inner &= y + 1 < r.y ? set.Row(y + 1, z)[w] : 0;
        inner &= z > 0 ? set.Row(y, z - 1)[w] : 0;
        inner &= z + 1 < r.z ? set.Row(y, z + 1)[w] : 0;
        o[w] = row[w] & ~inner;
      }
    }
  }
  return out;
}

}  // namespace nimbus
