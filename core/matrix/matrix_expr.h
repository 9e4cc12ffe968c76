// The expression language over IFS matrices: immutable expression trees
// (union, composition, tensor products, block diagonals, concatenation),
// their expansion into a concrete matrix with limits and a report, and the
// catalog of named matrices that spec references resolve against.
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/matrix/ifs_matrix_core.h"
#include "core/matrix/map_table.h"

namespace nimbus {

enum class MatrixOp {
  kLeaf,
  kUnion,          // (H u K)_ij = H_ij u K_ij                  (n-ary, same size)
  kIntersection,   // (H n K)_ij = H_ij n K_ij                  (n-ary, same size)
  kComposition,    // (H o K)_ij = u_k { f o g : f in H_ik, g in K_kj } (n-ary)
  kTensorProduct,  // (H (x) K)_(i*m+k, j*m+l) = H_ij u K_kl    (binary, n*m)
  kTensorSum,      // shuffle: [k==l] H_ij u [i==j] K_kl        (binary, n*m)
  kBlockDiagonal,  // diag(H, K, ...)                           (n-ary)
  kConcatenation,  // diag(H, K) plus identity links H-state -> K-state
};

/// Name of an operation as used in expression descriptions ("union", ...).
std::string_view MatrixOpName(MatrixOp op);

/// Identity link of a concatenation: state `from` of the left operand gets
/// the identity map towards state `to` of the right operand.
struct MatrixLink {
  uint32_t from = 0;
  uint32_t to = 0;
};

struct MatrixExpr;
using MatrixExprPtr = std::shared_ptr<const MatrixExpr>;

/// @brief One node of an immutable expression tree over IFS matrices.
/// Subtrees may be shared. `name` is the matrix name of a leaf; on inner
/// nodes it is an optional label used in reports and error messages
/// instead of the generated description.
struct MatrixExpr {
  MatrixOp op = MatrixOp::kLeaf;
  std::string name;
  IfsMatrix matrix;                     // leaves only
  std::vector<MatrixExprPtr> operands;  // inner nodes only
  std::vector<MatrixLink> links;        // concatenation only
};

MatrixExprPtr MatrixLeaf(std::string name, IfsMatrix matrix);
MatrixExprPtr MatrixUnion(std::vector<MatrixExprPtr> operands);
MatrixExprPtr MatrixIntersection(std::vector<MatrixExprPtr> operands);
/// Left to right: compose({H, K, L}) = H o K o L.
MatrixExprPtr MatrixComposition(std::vector<MatrixExprPtr> operands);
MatrixExprPtr MatrixTensorProduct(MatrixExprPtr a, MatrixExprPtr b);
MatrixExprPtr MatrixTensorSum(MatrixExprPtr a, MatrixExprPtr b);
MatrixExprPtr MatrixBlockDiagonal(std::vector<MatrixExprPtr> operands);
/// Empty `links` means the single link (last state of a) -> (first state of b).
MatrixExprPtr MatrixConcatenation(MatrixExprPtr a, MatrixExprPtr b,
                                  std::vector<MatrixLink> links = {});
/// A copy of `expr` whose node carries `label`.
MatrixExprPtr MatrixLabeled(std::string label, MatrixExprPtr expr);

/// "union(tree, sum(a, b))"-style text; labels replace whole subtrees.
std::string DescribeMatrixExpr(const MatrixExpr& expr);

/// Caps on expansion; evaluation stops with ResourceExhausted naming the
/// sub-expression that would cross one.
struct ExpansionLimits {
  uint32_t max_size = 512;                          // n of any sub-result
  uint64_t max_map_references = uint64_t{1} << 20;  // per sub-result
  size_t max_table_maps = size_t{1} << 16;          // map table after compositions
};

/// One expanded sub-expression, reported in evaluation (post-)order.
struct ExpansionStep {
  std::string expression;
  int depth = 0;  // 0 = the root
  uint32_t size = 0;
  uint64_t map_references = 0;
};

/// @brief Expands an expression into a concrete matrix, appending composed
/// maps (and the identity, for concatenation links) to `table`. Operand
/// mismatches are InvalidArgument and limit breaches ResourceExhausted, both
/// naming the offending sub-expression. Aperiodicity is not required of
/// operands or result here; check the result with CheckAperiodic.
absl::StatusOr<IfsMatrix> EvaluateMatrixExpr(const MatrixExpr& expr, MapTable& table,
                                             const ExpansionLimits& limits = {},
                                             std::vector<ExpansionStep>* report = nullptr);

/// @brief Named matrices for the spec layer's references.
class MatrixCatalog {
 public:
  /// AlreadyExists for a duplicate name, InvalidArgument for an empty one.
  absl::Status Add(std::string name, IfsMatrix matrix);
  /// The leaf expression for `name`; NotFound lists the known names.
  absl::StatusOr<MatrixExprPtr> Find(std::string_view name) const;

 private:
  std::map<std::string, MatrixExprPtr, std::less<>> leaves_;
};

}  // namespace nimbus
