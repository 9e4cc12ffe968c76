// Sparse integer visit counters over a GridFrame: the accumulator of every
// chaos game and set iteration.
#pragma once

#include <cstdint>
#include <cstdlib>
#include <memory>
#include <vector>

#include "core/base/geometry.h"
#include "core/grid/tile_arena.h"

namespace nimbus {

/// @brief Sparse uint32 counters on a voxel lattice, stored as lazily
/// allocated 32^3 tiles (128 KiB, an eighth of this machine's L2), so memory
/// follows the active region and a binned batch of increments to one tile
/// stays in cache. Inside a tile, 8^3 leaves are laid out in OpenVDB's
/// LeafNode order so conversion to a VDB tree copies whole leaves.
///
/// A grid one voxel thick in z (resolution z == 1, a 2D picture as a
/// volume) would waste 31/32 of every tile, so it folds 32 rows into the
/// tile's depth: voxel (x, y, 0) is stored at (x, y >> 5, y & 31), the
/// layout of ImagePlane's pixels, and a tile holds 32 columns by 1024 rows.
/// Key, Add, Get and ForEachVoxel speak in voxels whatever the layout;
/// tiles(), TileOrigin and ForEachTile are in the stored layout.
///
/// Optionally each voxel also carries a colour sum: the exact integer sum
/// of the 16-bit fixed-point colour coordinates of its visits, so colour
/// adds up order-independently (bitwise reproducible for any thread count).
///
/// Not thread-safe: each thread owns one CountGrid and they are merged, or
/// the threads share one behind SharedTiles' locks (core/chaos).
class CountGrid {
 public:
  static constexpr int kTileLog2 = 5;
  static constexpr int kTileDim = 1 << kTileLog2;  // 32
  static constexpr int kTileVoxels = kTileDim * kTileDim * kTileDim;
  static constexpr int kLeafDim = 8;

  /// Colour coordinates are quantised to this many levels (16 bits).
  static constexpr uint32_t kColorScale = 65535;
  static constexpr int kColorShift = 48;
  /// Keys may carry a weight (for trilinear splatting) in bits 40..45,
  /// stored as weight - 1 so plain keys weigh 1.
  static constexpr int kWeightShift = 40;
  static constexpr uint32_t kMaxWeight = 64;
  static constexpr uint64_t kVoxelMask = (uint64_t{1} << kWeightShift) - 1;

  explicit CountGrid(Int3 resolution, bool with_color = false);
  CountGrid(CountGrid&&) noexcept;
  CountGrid& operator=(CountGrid&&) noexcept;
  ~CountGrid();

  /// True for the resolutions stored folded (z == 1).
  static bool Folds(Int3 resolution) { return resolution.z == 1; }
  /// The lattice the tiles cover: the resolution, or (x, ceil(y / 32), 32)
  /// folded.
  static Int3 StorageResolution(Int3 resolution) {
    return Folds(resolution) ? Int3{resolution.x, (resolution.y + kTileDim - 1) >> kTileLog2,
                                    kTileDim}
                             : resolution;
  }
  /// Tiles of a grid of this resolution, all allocated.
  static uint64_t TileCountFor(Int3 resolution);
  /// Voxels of the resolution one tile spans along each axis: 32^3, or 32
  /// columns by 1024 rows by 32 (more than the one slice) folded.
  static Int3 TileSpan(Int3 resolution) {
    return Folds(resolution) ? Int3{kTileDim, kTileDim << kTileLog2, kTileDim}
                             : Int3{kTileDim, kTileDim, kTileDim};
  }

  /// VDB leaves (8^3 voxels) one tile's voxels fall in: 64, or 512 folded.
  static uint64_t LeavesPerTile(Int3 resolution) { return Folds(resolution) ? 512 : 64; }

  Int3 resolution() const { return res_; }
  /// Tiles per axis of the stored layout.
  Int3 tiles() const { return tiles_; }
  bool folded() const { return fold_shift_ != 0; }
  /// The fold as walk::AffineWalk takes it: y is stored at
  /// (y >> fold_shift, z + (y & fold_mask)); both 0 unfolded.
  uint32_t fold_shift() const { return fold_shift_; }
  uint32_t fold_mask() const { return fold_mask_; }

  /// Packs a voxel into a key: tile index << 15 | offset inside the tile.
  uint64_t Key(int x, int y, int z) const {
    // Branch-free fold: shift and mask are 0 for an unfolded grid.
    const int sy = y >> fold_shift_, sz = z + int(uint32_t(y) & fold_mask_);
    const uint64_t tile =
        (uint64_t(x >> kTileLog2) * tiles_.y + uint64_t(sy >> kTileLog2)) * tiles_.z +
        uint64_t(sz >> kTileLog2);
    return (tile << 15) | LocalOffset(x & 31, sy & 31, sz & 31);
  }
  static uint32_t LocalOffset(int lx, int ly, int lz) {
    // leaf (lx>>3, ly>>3, lz>>3) then OpenVDB's (x<<6 | y<<3 | z) in the leaf.
    return (uint32_t(((lx >> 3) << 4) | ((ly >> 3) << 2) | (lz >> 3)) << 9) |
           uint32_t(((lx & 7) << 6) | ((ly & 7) << 3) | (lz & 7));
  }

  /// A key with a quantised colour coordinate (0..kColorScale) attached.
  static uint64_t WithColor(uint64_t key, uint32_t color16) {
    return key | (uint64_t(color16) << kColorShift);
  }
  bool has_color() const { return with_color_; }
  /// A key with a weight in 1..kMaxWeight attached.
  static uint64_t WithWeight(uint64_t key, uint32_t weight) {
    return key | (uint64_t(weight - 1) << kWeightShift);
  }
  static uint32_t WeightOf(uint64_t key) { return uint32_t((key >> kWeightShift) & 63) + 1; }

  /// Adds `n` times the key's weight to the voxel with this key (and as
  /// many times its colour).
  void AddKey(uint64_t key, uint32_t n = 1) {
    const uint64_t tile = (key & kVoxelMask) >> 15;
    const uint32_t off = uint32_t(key & 0x7fff);
    const uint32_t add = n * WeightOf(key);
    TileFor(tile)[off] += add;
    if (with_color_) ColorTileFor(tile)[off] += uint64_t(add) * (key >> kColorShift);
  }
  void Add(int x, int y, int z, uint32_t n = 1) { AddKey(Key(x, y, z), n); }

  /// The counters of tile `tile` (allocated on first use), indexed by
  /// LocalOffset: for writers that bin their own increments.
  uint32_t* MutableTile(uint64_t tile) { return TileFor(tile); }
  /// Same, but null where the tile is not allocated yet. It never
  /// allocates, so a thread sharing the grid (SharedTiles) may call it
  /// without the allocation lock for a tile no other thread writes.
  uint32_t* MutableTileOrNull(uint64_t tile) { return table_[tile]; }
  /// The colour sums of tile `tile`, after MutableTile(tile) allocated it;
  /// nullptr without colour.
  uint64_t* MutableColorTile(uint64_t tile) { return with_color_ ? ColorTileFor(tile) : nullptr; }

  /// Read-only counters (colour sums) of tile `tile`, nullptr if never
  /// allocated (or without colour): for readers that visit leaves in an
  /// order of their own, e.g. a VDB tree's.
  const uint32_t* TileOrNull(uint64_t tile) const { return table_[tile]; }
  const uint64_t* ColorTileOrNull(uint64_t tile) const {
    return with_color_ ? color_[tile] : nullptr;
  }

  uint32_t Get(int x, int y, int z) const;
  /// Sum of the colour coordinates (units of 1/kColorScale); 0 without colour.
  uint64_t GetColorSum(int x, int y, int z) const;

  /// Adds every counter of `other` (same resolution), saturating at 2^32-1.
  void Merge(const CountGrid& other);
  /// Adds one tile's counters (and colour sums, when both have them) to
  /// tile `tile` (< TileCount()), saturating as Merge does.
  void AddTile(uint64_t tile, const uint32_t* counts, const uint64_t* colors);
  size_t TileCount() const { return table_.size(); }
  /// The largest counter and the sum of all, tiles reduced in parallel in
  /// one pass (a result's writers record both).
  struct Sums {
    uint32_t max = 0;
    uint64_t total = 0;
  };
  Sums MaxAndTotal() const;
  /// Sum of all counters and the largest counter.
  uint64_t Total() const { return MaxAndTotal().total; }
  uint32_t Max() const { return MaxAndTotal().max; }
  size_t AllocatedTiles() const { return allocated_; }
  /// Caps the tiles this grid allocates (0: no cap). Increments to tiles
  /// beyond the cap land in a scratch tile and set overflowed(): the owner
  /// then abandons the run instead of running the machine out of memory.
  void SetTileLimit(size_t max_tiles) { tile_limit_ = max_tiles; }
  /// Transparent huge pages from the first block of tiles on (TileArena):
  /// for owners that expect to fill most of a small grid's tiles, where 4
  /// KiB pages would only add page faults.
  void PreferHugePages() {
    arena_.PreferHugePages();
    color_arena_.PreferHugePages();
  }
  bool overflowed() const { return overflowed_; }
  size_t MemoryBytes() const;
  /// Worst-case bytes for a grid of this resolution (every tile allocated).
  static uint64_t MaxMemoryBytes(Int3 resolution);
  /// Bytes of one allocated tile (counts, plus colour sums if enabled).
  static uint64_t TileBytes(bool with_color) {
    return uint64_t(kTileVoxels) * (sizeof(uint32_t) + (with_color ? sizeof(uint64_t) : 0));
  }
  /// Bytes for a grid whose allocated tiles are bounded by `max_tiles`.
  static uint64_t BoundedMemoryBytes(Int3 resolution, uint64_t max_tiles, bool with_color);

  /// Calls f(tile_origin, const uint32_t* tile) for every allocated tile,
  /// in tile-index order (deterministic). The origin and the tile's local
  /// offsets are in the stored layout: VoxelAt turns them into a voxel.
  template <typename F>
  void ForEachTile(F&& f) const {
    for (size_t t = 0; t < table_.size(); ++t)
      if (table_[t]) f(TileOrigin(t), table_[t]);
  }
  /// Same, with the tile's colour sums (nullptr without colour).
  template <typename F>
  void ForEachTileWithColor(F&& f) const {
    for (size_t t = 0; t < table_.size(); ++t)
      if (table_[t]) f(TileOrigin(t), table_[t], with_color_ ? color_[t] : nullptr);
  }
  Int3 TileOrigin(size_t t) const {
    const int z = int(t % tiles_.z), y = int((t / tiles_.z) % tiles_.y),
              x = int(t / (size_t(tiles_.z) * tiles_.y));
    return {x * kTileDim, y * kTileDim, z * kTileDim};
  }
  /// The voxel stored at local offset `offset` of the tile at `origin`
  /// (a TileOrigin); past the resolution for padding voxels.
  Int3 VoxelAt(Int3 origin, uint32_t offset) const {
    const Int3 l = LocalCoord(offset);
    const int sy = origin.y + l.y, sz = origin.z + l.z;
    return {origin.x + l.x, (sy << fold_shift_) | (sz & int(fold_mask_)),
            sz & ~int(fold_mask_)};
  }
  /// Calls f(Int3 voxel, uint32_t count) for every non-zero counter, tile
  /// by tile in tile-index order.
  template <typename F>
  void ForEachVoxel(F&& f) const {
    ForEachTile([&](Int3 o, const uint32_t* t) {
      for (uint32_t i = 0; i < uint32_t(kTileVoxels); ++i)
        if (t[i]) f(VoxelAt(o, i), t[i]);
    });
  }
  /// Calls f(Int3 leaf_origin, const uint32_t* counts, const uint64_t*
  /// colors) for every 8^3 leaf of voxels with a non-zero counter, its 512
  /// counters (and colour sums, nullptr without colour) in OpenVDB's
  /// LeafNode order: what a VDB tree of the voxels holds, leaf by leaf.
  /// Unfolded these are slices of the tiles; folded, each stored leaf holds
  /// eight voxel leaves' only slice, gathered into a buffer.
  template <typename F>
  void ForEachLeaf(F&& f) const {
    ForEachLeafInTiles(0, table_.size(), f);
  }
  /// ForEachLeaf over tiles [begin, end) only (< TileCount()): disjoint
  /// ranges may be walked on several threads.
  template <typename F>
  void ForEachLeafInTiles(size_t begin, size_t end, F&& f) const {
    auto tiles = [&](auto&& g) {
      for (size_t t = begin; t < end; ++t)
        if (table_[t]) g(TileOrigin(t), table_[t], with_color_ ? color_[t] : nullptr);
    };
    if (!folded()) {
      tiles([&](Int3 o, const uint32_t* t, const uint64_t* c) {
        for (int leaf = 0; leaf < 64; ++leaf) {
          const uint32_t* v = t + leaf * 512;
          if (AllZero(v, 512)) continue;
          f(Int3{o.x + ((leaf >> 4) & 3) * 8, o.y + ((leaf >> 2) & 3) * 8, o.z + (leaf & 3) * 8},
            v, c ? c + leaf * 512 : nullptr);
        }
      });
      return;
    }
    uint32_t v[512] = {};
    uint64_t cs[512] = {};
    tiles([&](Int3 o, const uint32_t* t, const uint64_t* c) {
      for (int leaf = 0; leaf < 64; ++leaf) {
        const int x0 = o.x + ((leaf >> 4) & 3) * 8, sy0 = o.y + ((leaf >> 2) & 3) * 8,
                  sz0 = o.z + (leaf & 3) * 8;
        const uint32_t* lv = t + leaf * 512;
        // Stored (x, sy, sz) is voxel (x, 32 sy + sz, 0): fixing sy gives
        // the z = 0 slice of one voxel leaf, offset x << 6 | (sz & 7) << 3.
        for (int j = 0; j < 8; ++j) {
          bool any = false;
          for (int i = 0; i < 8; ++i)
            for (int k = 0; k < 8; ++k) {
              const uint32_t n = lv[(i << 6) | (j << 3) | k];
              v[(i << 6) | (k << 3)] = n;
              any = any || n;
            }
          if (!any) continue;
          if (c)
            for (int i = 0; i < 8; ++i)
              for (int k = 0; k < 8; ++k)
                cs[(i << 6) | (k << 3)] = c[leaf * 512 + ((i << 6) | (j << 3) | k)];
          f(Int3{x0, ((sy0 + j) << kTileLog2) + sz0, 0}, v, c ? cs : nullptr);
        }
      }
    });
  }
  /// Voxel coordinates (relative to its tile's origin) of a local offset.
  static Int3 LocalCoord(uint32_t offset) {
    const uint32_t leaf = offset >> 9, v = offset & 511;
    return {int(((leaf >> 4) & 3) * 8 + (v >> 6)), int(((leaf >> 2) & 3) * 8 + ((v >> 3) & 7)),
            int((leaf & 3) * 8 + (v & 7))};
  }

 private:
  uint32_t* TileFor(uint64_t tile) {
    uint32_t* p = table_[tile];
    if (!p) [[unlikely]]
      return Allocate(tile);
    return p;
  }
  uint64_t* ColorTileFor(uint64_t tile) {
    uint64_t* p = color_[tile];
    return p ? p : spill_color_;  // null only past the tile limit
  }
  // Allocates the tile, or returns the scratch tile past the limit.
  uint32_t* Allocate(uint64_t tile);
  static bool AllZero(const uint32_t* v, int n) {
    for (int i = 0; i < n; ++i)
      if (v[i]) return false;
    return true;
  }

  Int3 res_;
  Int3 tiles_;  // of the stored layout
  uint32_t fold_shift_ = 0, fold_mask_ = 0;
  bool with_color_ = false;
  // Counters and colour sums come from fresh pages (huge ones for large
  // grids), which are already zero: a new tile costs no memset, and a big
  // grid few page faults. Colour tiles used to come from calloc, whose
  // 256 KiB blocks are mapped one at a time and fault in 64 times each.
  TileArena arena_{kTileVoxels * sizeof(uint32_t)};
  TileArena color_arena_{kTileVoxels * sizeof(uint64_t)};
  std::vector<uint32_t*> table_;
  std::vector<uint64_t*> color_;  // parallel to table_ when with_color_
  size_t allocated_ = 0;
  size_t tile_limit_ = 0;
  bool overflowed_ = false;
  uint32_t* spill_ = nullptr;  // the scratch tile, once needed
  uint64_t* spill_color_ = nullptr;
};

}  // namespace nimbus
