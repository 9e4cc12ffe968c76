// @brief An independent oracle for the explorer's contraction test: the
// largest singular value and |det| of a small square matrix, by cyclic
// Jacobi rotations on A^T A and by Gaussian elimination, sharing no code
// with core/chaos/random_ifs.cc (which uses closed forms).
#pragma once

#include <vector>

namespace nimbus::testing {

/// A dense n x n matrix, rows first.
using SquareMatrix = std::vector<std::vector<double>>;

/// Largest singular value of `a` (n <= 8).
double OracleLargestSingularValue(const SquareMatrix& a);
/// |det a| by Gaussian elimination with partial pivoting.
double OracleAbsDeterminant(SquareMatrix a);

/// The top-left `dims` x `dims` block of a 12-number row-major affine
/// matrix [a b c tx; d e f ty; g h i tz].
SquareMatrix LinearBlock(const std::vector<double>& values12, int dims);

}  // namespace nimbus::testing
