// Independent references for fractal-field tests: the variance a weight
// rule implies, and the radially averaged power spectrum of a 2D field with
// its log-log slope; and the field builder the tests and the bench share.
#pragma once

#include <cstdint>
#include <vector>

#include "core/field/field_recipe.h"

namespace nimbus::testing {

/// `count` meshes from `base` (per axis) by the ratio 1/2, staggered, with
/// weights (c_k / c_0)^hurst (kPower) or by cell volume; n = dims axes of
/// which `space_dims` are spatial.
FractalFieldParams SeriesParams(int dims, int space_dims, FieldInterpolation interp, FieldVec base,
                                int count, double hurst, uint64_t seed,
                                WeightRule rule = WeightRule::kPower);

/// Variance of Σ p_k f_k at uniformly random points when every f_k is an
/// n-linear interpolation of independent node values uniform on [-1, 1):
/// Σ p_k² · (1/3) · (2/3)^n (per axis E[(1-t)² + t²] = 2/3).
double LinearFieldVariance(const std::vector<double>& weights, int dims);

/// Radially averaged power |F(k)|² of an n x n real image (n a power of
/// two, row-major), by a plain radix-2 FFT; bin r holds wavenumbers with
/// round(|k|) = r, r = 0..n/2.
std::vector<double> RadialPowerSpectrum(const std::vector<double>& image, int n);

/// Least-squares slope of log(power) against log(r) over bins [r0, r1].
double LogLogSlope(const std::vector<double>& power, int r0, int r1);

}  // namespace nimbus::testing
