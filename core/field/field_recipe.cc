#include "core/field/field_recipe.h"

#include <cmath>

#include "absl/strings/str_cat.h"

namespace nimbus {

namespace {

// Fractional parts of k * sqrt(p) for the first primes: well spread, never
// repeating, the same on every machine.
constexpr double kStagger[kMaxFieldDims] = {1.4142135623730951, 1.7320508075688772,
                                            2.2360679774997896, 2.6457513110645907};

double GeometricMeanCell(const FieldMesh& m, int dims) {
  double log_sum = 0;
  for (int i = 0; i < dims; ++i) log_sum += std::log(m.cell[i]);
  return std::exp(log_sum / dims);
}

}  // namespace

std::vector<FieldMesh> ExpandMeshSeries(const MeshSeries& series, int dims) {
  std::vector<FieldMesh> meshes(size_t(std::max(series.count, 0)));
  double scale = 1;
  for (size_t k = 0; k < meshes.size(); ++k, scale *= series.ratio) {
    for (int i = 0; i < dims; ++i) {
      meshes[k].cell[i] = series.base_cell[i] * scale;
      if (!series.aligned) {
        const double a = double(k) * kStagger[i];
        meshes[k].offset[i] = a - std::floor(a);
      }
    }
  }
  return meshes;
}

absl::Status ApplyWeightRule(WeightRule rule, double amplitude, double hurst,
                             const std::vector<double>& explicit_weights, int dims,
                             std::vector<FieldMesh>& meshes) {
  if (meshes.empty()) return absl::OkStatus();
  if (rule == WeightRule::kExplicit) {
    if (explicit_weights.size() != meshes.size())
      return absl::InvalidArgumentError(absl::StrCat("weights.explicit: needs one weight per mesh (",
                                                     meshes.size(), "), got ",
                                                     explicit_weights.size()));
    for (size_t k = 0; k < meshes.size(); ++k) {
      if (!std::isfinite(explicit_weights[k]))
        return absl::InvalidArgumentError(
            absl::StrCat("weights.explicit[", k, "]: must be finite, got ", explicit_weights[k]));
      meshes[k].weight = explicit_weights[k];
    }
    return absl::OkStatus();
  }
  const double c0 = GeometricMeanCell(meshes[0], dims);
  for (FieldMesh& m : meshes) {
    // Both rules are powers of the cell size: volume is (c_k / c_0)^n.
    const double ratio = GeometricMeanCell(m, dims) / c0;
    const double exponent = rule == WeightRule::kCellVolume ? double(dims) : hurst;
    m.weight = amplitude * std::pow(ratio, exponent);
  }
  return absl::OkStatus();
}

void SnapCellsToPeriods(FractalFieldParams& params, std::vector<std::string>* notes) {
  for (int i = 0; i < params.dims; ++i) {
    const double period = params.mapping.period[i];
    if (!(period > 0)) continue;
    for (size_t k = 0; k < params.meshes.size(); ++k) {
      FieldMesh& m = params.meshes[k];
      const double nodes = std::max(1.0, std::round(period / m.cell[i]));
      const double snapped = period / nodes;
      if (notes && std::abs(snapped - m.cell[i]) > 1e-9 * m.cell[i])
        notes->push_back(absl::StrCat("meshes[", k, "].cell[", i, "]: ", m.cell[i],
                                      " snapped to ", snapped, " (", nodes,
                                      " cells per period of ", period, ")"));
      m.cell[i] = snapped;
      m.period_nodes[i] = int64_t(nodes);
    }
  }
}

}  // namespace nimbus
