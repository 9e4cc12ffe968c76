// The gap filling's pretest (core/sets/set_maps.cc, AddMidpoints): which
// moving voxels of one 64-bit row word have a neighbour whose image lies two
// or more voxels from theirs, so that a bridge may be needed. About one
// moving voxel in five passes; the others are ruled out here, 64 voxels at a
// time. Portable, AVX2-level (BMI2 and POPCNT) and AVX-512 versions give the
// same mask; core/base/cpu_dispatch.h picks one at run time.
//
// Everything here is plain data: the per-ISA translation units include only
// this header, because an inline function compiled there with wider
// instructions enabled could be the copy the linker keeps for the rest of
// the program.
#pragma once

#include <cstdint>

namespace nimbus::gap {

/// @brief One row word of moving voxels with its neighbourhood, as bit
/// words (bit b stands for voxel x = x0 + b of row (y, z)) and images.
/// Images are packed voxels (x | y << 10 | z << 20) indexed by rank: the
/// moving voxels of a row word, and the moving voxels of a row in x order,
/// have consecutive ranks.
struct Word {
  uint64_t mov = 0;       // the moving voxels
  uint64_t still[6] = {};  // neighbour in direction k (-x, +x, -y, +y, -z, +z) stays put
  // Neighbour along +x, +y, +z moves (moving pairs along -x, -y, -z are
  // tested from the other voxel).
  uint64_t moves_x = 0, moves_y = 0, moves_z = 0;
  const uint32_t* images = nullptr;  // image of the word's first moving voxel, then on
  // Images of the moving voxels of the same word of rows (y + 1, z) and
  // (y, z + 1), from the first; read only when moves_y / moves_z are set.
  const uint32_t* images_y = nullptr;
  const uint32_t* images_z = nullptr;
  int x0 = 0, y = 0, z = 0;
};

/// The members of `mov` that need the full test: a neighbour that stays
/// put at a + e while the voxel's image m has max |m - a - e| >= 2, or a
/// moving neighbour along +x, +y or +z whose image is two or more voxels
/// (Chebyshev) from m.
uint64_t NeedPortable(const Word& w);
uint64_t NeedAvx2(const Word& w);    // the portable code built with BMI2 and POPCNT
uint64_t NeedAvx512(const Word& w);  // 16 voxels per step; needs BMI2 as well

using NeedFn = uint64_t (*)(const Word&);

/// The version for `level` (0 portable, 1 AVX2, 2 AVX-512, as SimdLevel),
/// lowered to what this CPU runs; NeedKernel() uses ActiveSimd().
NeedFn NeedKernel(int level);
NeedFn NeedKernel();

}  // namespace nimbus::gap
