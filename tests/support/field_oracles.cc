#include "tests/support/field_oracles.h"

#include <cmath>
#include <complex>

namespace nimbus::testing {

namespace {

using Complex = std::complex<double>;

// In-place iterative radix-2 FFT of a power-of-two length line.
void Fft(std::vector<Complex>& a) {
  const size_t n = a.size();
  for (size_t i = 1, j = 0; i < n; ++i) {
    size_t bit = n >> 1;
    for (; j & bit; bit >>= 1) j ^= bit;
    j ^= bit;
    if (i < j) std::swap(a[i], a[j]);
  }
  for (size_t len = 2; len <= n; len <<= 1) {
    const Complex w = std::polar(1.0, -2 * M_PI / double(len));
    for (size_t i = 0; i < n; i += len) {
      Complex wk = 1;
      for (size_t k = 0; k < len / 2; ++k, wk *= w) {
        const Complex u = a[i + k], v = a[i + k + len / 2] * wk;
        a[i + k] = u + v;
        a[i + k + len / 2] = u - v;
      }
    }
  }
}

}  // namespace

FractalFieldParams SeriesParams(int dims, int space_dims, FieldInterpolation interp, FieldVec base,
                                int count, double hurst, uint64_t seed, WeightRule rule) {
  FractalFieldParams p;
  p.dims = dims;
  p.mapping.space_dims = space_dims;
  p.interpolation = interp;
  p.seed = seed;
  MeshSeries s;
  s.base_cell = base;
  s.count = count;
  p.meshes = ExpandMeshSeries(s, dims);
  (void)ApplyWeightRule(rule, 1, hurst, {}, dims, p.meshes);
  return p;
}

double LinearFieldVariance(const std::vector<double>& weights, int dims) {
  double sum = 0;
  for (double p : weights) sum += p * p;
  return sum / 3 * std::pow(2.0 / 3, dims);
}

std::vector<double> RadialPowerSpectrum(const std::vector<double>& image, int n) {
  const size_t len = static_cast<size_t>(n);
  std::vector<std::vector<Complex>> rows(len, std::vector<Complex>(len));
  double mean = 0;
  for (double v : image) mean += v;
  mean /= double(image.size());
  for (int r = 0; r < n; ++r) {
    for (int c = 0; c < n; ++c) rows[size_t(r)][size_t(c)] = image[size_t(r) * n + c] - mean;
    Fft(rows[size_t(r)]);
  }
  std::vector<Complex> col(len);
  std::vector<double> power(len / 2 + 1, 0.0), count(len / 2 + 1, 0.0);
  for (int c = 0; c < n; ++c) {
    for (int r = 0; r < n; ++r) col[size_t(r)] = rows[size_t(r)][size_t(c)];
    Fft(col);
    for (int r = 0; r < n; ++r) {
      const int kx = c <= n / 2 ? c : c - n, ky = r <= n / 2 ? r : r - n;
      const int bin = int(std::lround(std::sqrt(double(kx * kx + ky * ky))));
      if (bin > n / 2) continue;
      power[size_t(bin)] += std::norm(col[size_t(r)]);
      count[size_t(bin)] += 1;
    }
  }
  for (size_t b = 0; b < power.size(); ++b)
    if (count[b] > 0) power[b] /= count[b];
  return power;
}

double LogLogSlope(const std::vector<double>& power, int r0, int r1) {
  double sx = 0, sy = 0, sxx = 0, sxy = 0;
  int n = 0;
  for (int r = r0; r <= r1; ++r) {
    const double x = std::log(double(r)), y = std::log(power[size_t(r)]);
    sx += x;
    sy += y;
    sxx += x * x;
    sxy += x * y;
    ++n;
  }
  return (n * sxy - sx * sy) / (n * sxx - sx * sx);
}

}  // namespace nimbus::testing
