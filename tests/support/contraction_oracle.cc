#include "tests/support/contraction_oracle.h"

#include <algorithm>
#include <cmath>
#include <utility>

namespace nimbus::testing {

double OracleLargestSingularValue(const SquareMatrix& a) {
  const size_t n = a.size();
  SquareMatrix g(n, std::vector<double>(n, 0.0));
  for (size_t i = 0; i < n; ++i)
    for (size_t j = 0; j < n; ++j)
      for (size_t k = 0; k < n; ++k) g[i][j] += a[k][i] * a[k][j];
  // Cyclic Jacobi: rotate away each off-diagonal entry until none is left;
  // the diagonal then holds the eigenvalues of the Gram matrix.
  for (int sweep = 0; sweep < 100; ++sweep) {
    double off = 0;
    for (size_t p = 0; p < n; ++p)
      for (size_t q = p + 1; q < n; ++q) off += g[p][q] * g[p][q];
    if (off < 1e-30) break;
    for (size_t p = 0; p < n; ++p)
      for (size_t q = p + 1; q < n; ++q) {
        if (g[p][q] == 0) continue;
        const double theta = 0.5 * std::atan2(2 * g[p][q], g[q][q] - g[p][p]);
        const double c = std::cos(theta), s = std::sin(theta);
        for (size_t k = 0; k < n; ++k) {  // columns p, q
          const double gp = g[k][p], gq = g[k][q];
          g[k][p] = c * gp - s * gq;
          g[k][q] = s * gp + c * gq;
        }
        for (size_t k = 0; k < n; ++k) {  // rows p, q
          const double gp = g[p][k], gq = g[q][k];
          g[p][k] = c * gp - s * gq;
          g[q][k] = s * gp + c * gq;
        }
      }
  }
  double largest = 0;
  for (size_t i = 0; i < n; ++i) largest = std::max(largest, g[i][i]);
  return std::sqrt(largest);
}

double OracleAbsDeterminant(SquareMatrix a) {
  const size_t n = a.size();
  double det = 1;
  for (size_t col = 0; col < n; ++col) {
    size_t pivot = col;
    for (size_t r = col + 1; r < n; ++r)
      if (std::fabs(a[r][col]) > std::fabs(a[pivot][col])) pivot = r;
    if (a[pivot][col] == 0) return 0;
    std::swap(a[pivot], a[col]);
    det *= a[col][col];
    for (size_t r = col + 1; r < n; ++r) {
      const double f = a[r][col] / a[col][col];
      for (size_t k = col; k < n; ++k) a[r][k] -= f * a[col][k];
    }
  }
  return std::fabs(det);
}

SquareMatrix LinearBlock(const std::vector<double>& v, int dims) {
  SquareMatrix out(static_cast<size_t>(dims), std::vector<double>(static_cast<size_t>(dims)));
  for (int r = 0; r < dims; ++r)
    for (int c = 0; c < dims; ++c) out[size_t(r)][size_t(c)] = v[size_t(r * 4 + c)];
  return out;
}

}  // namespace nimbus::testing
