#include "core/matrix/matrix_expr.h"

#include <algorithm>
#include <iterator>
#include <utility>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "core/base/status_macros.h"
#include "core/matrix/matrix_text.h"

namespace nimbus {

using matrix_internal::CellText;
using matrix_internal::NameList;
using matrix_internal::Quoted;

namespace {

std::string OpName(MatrixOp op) { return std::string(MatrixOpName(op)); }

IfsMatrix::Entry SetUnion(const IfsMatrix::Entry& a, const IfsMatrix::Entry& b) {
  IfsMatrix::Entry out;
  out.reserve(a.size() + b.size());
  std::set_union(a.begin(), a.end(), b.begin(), b.end(), std::back_inserter(out));
  return out;
}

IfsMatrix::Entry SetIntersection(const IfsMatrix::Entry& a, const IfsMatrix::Entry& b) {
  IfsMatrix::Entry out;
  std::set_intersection(a.begin(), a.end(), b.begin(), b.end(), std::back_inserter(out));
  return out;
}

MatrixExprPtr MakeNode(MatrixOp op, std::vector<MatrixExprPtr> operands,
                       std::vector<MatrixLink> links = {}) {
  auto e = std::make_shared<MatrixExpr>();
  e->op = op;
  e->operands = std::move(operands);
  e->links = std::move(links);
  return e;
}

}  // namespace

std::string_view MatrixOpName(MatrixOp op) {
  switch (op) {
    case MatrixOp::kLeaf:
      return "leaf";
    case MatrixOp::kUnion:
      return "union";
    case MatrixOp::kIntersection:
      return "intersection";
    case MatrixOp::kComposition:
      return "compose";
    case MatrixOp::kTensorProduct:
      return "tensor_product";
    case MatrixOp::kTensorSum:
      return "tensor_sum";
    case MatrixOp::kBlockDiagonal:
      return "block_diag";
    case MatrixOp::kConcatenation:
      return "concat";
  }
  return "?";
}

MatrixExprPtr MatrixLeaf(std::string name, IfsMatrix matrix) {
  auto e = std::make_shared<MatrixExpr>();
  e->name = std::move(name);
  e->matrix = std::move(matrix);
  return e;
}
MatrixExprPtr MatrixUnion(std::vector<MatrixExprPtr> operands) {
  return MakeNode(MatrixOp::kUnion, std::move(operands));
}
MatrixExprPtr MatrixIntersection(std::vector<MatrixExprPtr> operands) {
  return MakeNode(MatrixOp::kIntersection, std::move(operands));
}
MatrixExprPtr MatrixComposition(std::vector<MatrixExprPtr> operands) {
  return MakeNode(MatrixOp::kComposition, std::move(operands));
}
MatrixExprPtr MatrixTensorProduct(MatrixExprPtr a, MatrixExprPtr b) {
  return MakeNode(MatrixOp::kTensorProduct, {std::move(a), std::move(b)});
}
MatrixExprPtr MatrixTensorSum(MatrixExprPtr a, MatrixExprPtr b) {
  return MakeNode(MatrixOp::kTensorSum, {std::move(a), std::move(b)});
}
MatrixExprPtr MatrixBlockDiagonal(std::vector<MatrixExprPtr> operands) {
  return MakeNode(MatrixOp::kBlockDiagonal, std::move(operands));
}
MatrixExprPtr MatrixConcatenation(MatrixExprPtr a, MatrixExprPtr b, std::vector<MatrixLink> links) {
  return MakeNode(MatrixOp::kConcatenation, {std::move(a), std::move(b)}, std::move(links));
}
MatrixExprPtr MatrixLabeled(std::string label, MatrixExprPtr expr) {
  auto e = std::make_shared<MatrixExpr>(*expr);
  e->name = std::move(label);
  return e;
}

std::string DescribeMatrixExpr(const MatrixExpr& expr) {
  if (!expr.name.empty()) return expr.name;
  if (expr.op == MatrixOp::kLeaf) return "<unnamed matrix>";
  std::vector<std::string> parts;
  for (const MatrixExprPtr& o : expr.operands)
    parts.push_back(o ? DescribeMatrixExpr(*o) : std::string("<null>"));
  for (const MatrixLink& l : expr.links) parts.push_back(absl::StrCat(l.from, "->", l.to));
  return absl::StrCat(OpName(expr.op), "(", absl::StrJoin(parts, ", "), ")");
}

namespace {

// Expands an expression bottom-up, enforcing the limits as results grow.
class Expander {
 public:
  Expander(MapTable& table, const ExpansionLimits& limits, std::vector<ExpansionStep>* report)
      : table_(table), limits_(limits), report_(report) {}

  absl::StatusOr<IfsMatrix> Eval(const MatrixExpr& e, int depth) {
    std::string what = DescribeMatrixExpr(e);
    if (what.size() > 160) what = what.substr(0, 157) + "...";
    absl::StatusOr<IfsMatrix> r = EvalNode(e, depth, what);
    if (r.ok() && report_) report_->push_back({what, depth, r->size(), r->MapReferences()});
    return r;
  }

 private:
  absl::StatusOr<IfsMatrix> EvalNode(const MatrixExpr& e, int depth, const std::string& what) {
    if (e.op == MatrixOp::kLeaf) {
      if (e.matrix.size() == 0)
        return absl::InvalidArgumentError(absl::StrCat("IFS matrix ", Quoted(what), " is empty"));
      NIMBUS_RETURN_IF_ERROR(ValidateMatrix(e.matrix, table_.size(), what));
      NIMBUS_RETURN_IF_ERROR(CheckSize(e.matrix.size(), what));
      NIMBUS_RETURN_IF_ERROR(CheckRefs(e.matrix.MapReferences(), what));
      return e.matrix;
    }
    const bool binary = e.op == MatrixOp::kTensorProduct || e.op == MatrixOp::kTensorSum ||
                        e.op == MatrixOp::kConcatenation;
    if (binary ? e.operands.size() != 2 : e.operands.empty())
      return absl::InvalidArgumentError(absl::StrCat(
          Quoted(what), ": ", OpName(e.op), " takes ",
          binary ? "exactly two operands" : "at least one operand", ", got ", e.operands.size()));
    std::vector<IfsMatrix> args;
    for (const MatrixExprPtr& o : e.operands) {
      if (!o) return absl::InvalidArgumentError(absl::StrCat(Quoted(what), ": null operand"));
      NIMBUS_ASSIGN_OR_RETURN(IfsMatrix m, Eval(*o, depth + 1));
      args.push_back(std::move(m));
    }
    switch (e.op) {
      case MatrixOp::kUnion:
      case MatrixOp::kIntersection:
      case MatrixOp::kComposition: {
        IfsMatrix acc = std::move(args[0]);
        for (size_t a = 1; a < args.size(); ++a) {
          if (args[a].size() != acc.size())
            return absl::InvalidArgumentError(
                absl::StrCat(Quoted(what), ": ", OpName(e.op), " needs equal sizes, got ",
                             acc.size(), " and ", args[a].size(), " (operand ", a + 1, ")"));
          NIMBUS_ASSIGN_OR_RETURN(acc, e.op == MatrixOp::kComposition
                                           ? Compose(acc, args[a], what)
                                           : Entrywise(acc, args[a], e.op, what));
        }
        return acc;
      }
      case MatrixOp::kTensorProduct:
      case MatrixOp::kTensorSum:
        return Tensor(args[0], args[1], e.op == MatrixOp::kTensorSum, what);
      case MatrixOp::kBlockDiagonal:
        return Blocks(args, {}, what);
      case MatrixOp::kConcatenation:
        return Blocks(args,
                      e.links.empty() ? std::vector<MatrixLink>{{args[0].size() - 1, 0}} : e.links,
                      what);
      case MatrixOp::kLeaf:
        break;
    }
    return absl::InternalError("unhandled matrix operation");
  }

  absl::Status CheckSize(uint64_t n, const std::string& what) const {
    if (n > limits_.max_size)
      return absl::ResourceExhaustedError(absl::StrCat("expanding ", Quoted(what), " gives a ", n,
                                                       " x ", n, " IFS matrix, above the limit of ",
                                                       limits_.max_size));
    return absl::OkStatus();
  }
  absl::Status CheckRefs(uint64_t refs, const std::string& what) const {
    if (refs > limits_.max_map_references)
      return absl::ResourceExhaustedError(
          absl::StrCat("expanding ", Quoted(what), " needs more than ", limits_.max_map_references,
                       " map references"));
    return absl::OkStatus();
  }

  absl::StatusOr<IfsMatrix> Entrywise(const IfsMatrix& a, const IfsMatrix& b, MatrixOp op,
                                      const std::string& what) {
    const uint32_t n = a.size();
    IfsMatrix out(n);
    uint64_t refs = 0;
    for (uint32_t i = 0; i < n; ++i)
      for (uint32_t j = 0; j < n; ++j) {
        IfsMatrix::Entry e = op == MatrixOp::kUnion ? SetUnion(a.at(i, j), b.at(i, j))
                                                    : SetIntersection(a.at(i, j), b.at(i, j));
        refs += e.size();
        NIMBUS_RETURN_IF_ERROR(CheckRefs(refs, what));
        out.Set(i, j, std::move(e));
      }
    return out;
  }

  absl::StatusOr<IfsMatrix> Compose(const IfsMatrix& a, const IfsMatrix& b,
                                    const std::string& what) {
    const uint32_t n = a.size();
    IfsMatrix out(n);
    uint64_t refs = 0;
    table_.set_max_maps(std::max(limits_.max_table_maps, table_.size()));
    for (uint32_t i = 0; i < n; ++i)
      for (uint32_t j = 0; j < n; ++j) {
        IfsMatrix::Entry e;
        uint64_t pairs = 0;
        for (uint32_t k = 0; k < n; ++k) {
          if (a.empty(i, k) || b.empty(k, j)) continue;
          // Bound the work before composing: every pair may be a new map.
          pairs += uint64_t{a.at(i, k).size()} * b.at(k, j).size();
          if (pairs > limits_.max_map_references)
            return absl::ResourceExhaustedError(
                absl::StrCat("expanding ", Quoted(what), " composes more than ",
                             limits_.max_map_references, " map pairs in entry ", CellText(i, j)));
          for (uint32_t f : a.at(i, k))
            for (uint32_t g : b.at(k, j)) {
              absl::StatusOr<uint32_t> fg = table_.Compose(f, g);
              if (!fg.ok())
                return absl::Status(fg.status().code(),
                                    absl::StrCat("in ", Quoted(what), " entry ", CellText(i, j),
                                                 ": ", fg.status().message()));
              e.push_back(*fg);
            }
        }
        std::sort(e.begin(), e.end());
        e.erase(std::unique(e.begin(), e.end()), e.end());
        refs += e.size();
        NIMBUS_RETURN_IF_ERROR(CheckRefs(refs, what));
        out.Set(i, j, std::move(e));
      }
    return out;
  }

  // Product: H_ij u K_kl everywhere. Sum (shuffle): the Kronecker sum
  // H (x) I u I (x) K with composition as the product, so the identity
  // entries vanish (id o f = f) and only [k==l] H_ij u [i==j] K_kl remains.
  absl::StatusOr<IfsMatrix> Tensor(const IfsMatrix& a, const IfsMatrix& b, bool sum,
                                   const std::string& what) {
    const uint32_t n = a.size(), m = b.size();
    NIMBUS_RETURN_IF_ERROR(CheckSize(uint64_t{n} * m, what));
    IfsMatrix out(n * m);
    static const IfsMatrix::Entry kNone;
    uint64_t refs = 0;
    for (uint32_t i = 0; i < n; ++i)
      for (uint32_t j = 0; j < n; ++j)
        for (uint32_t k = 0; k < m; ++k)
          for (uint32_t l = 0; l < m; ++l) {
            const IfsMatrix::Entry& x = (!sum || k == l) ? a.at(i, j) : kNone;
            const IfsMatrix::Entry& y = (!sum || i == j) ? b.at(k, l) : kNone;
            IfsMatrix::Entry e = SetUnion(x, y);
            refs += e.size();
            NIMBUS_RETURN_IF_ERROR(CheckRefs(refs, what));
            out.Set(i * m + k, j * m + l, std::move(e));
          }
    return out;
  }

  // Block diagonal of all operands; links (two operands) add the identity
  // from a state of the first block to a state of the second.
  absl::StatusOr<IfsMatrix> Blocks(const std::vector<IfsMatrix>& args,
                                   const std::vector<MatrixLink>& links, const std::string& what) {
    uint64_t total = 0, refs = links.size();
    for (const IfsMatrix& a : args) total += a.size(), refs += a.MapReferences();
    NIMBUS_RETURN_IF_ERROR(CheckSize(total, what));
    NIMBUS_RETURN_IF_ERROR(CheckRefs(refs, what));
    IfsMatrix out(static_cast<uint32_t>(total));
    uint32_t offset = 0;
    for (const IfsMatrix& a : args) {
      for (uint32_t i = 0; i < a.size(); ++i)
        for (uint32_t j = 0; j < a.size(); ++j) out.Set(offset + i, offset + j, a.at(i, j));
      offset += a.size();
    }
    if (!links.empty()) {
      table_.set_max_maps(std::max(limits_.max_table_maps, table_.size()));
      NIMBUS_ASSIGN_OR_RETURN(const uint32_t id, table_.Identity());
      const uint32_t n = args[0].size();
      for (const MatrixLink& l : links) {
        if (l.from >= n || l.to >= args[1].size())
          return absl::InvalidArgumentError(absl::StrCat(Quoted(what), ": link ", l.from, "->",
                                                         l.to, " is outside the operands' sizes ",
                                                         n, " and ", args[1].size()));
        out.Insert(l.from, n + l.to, id);
      }
    }
    return out;
  }

  MapTable& table_;
  const ExpansionLimits& limits_;
  std::vector<ExpansionStep>* report_;
};

}  // namespace

absl::StatusOr<IfsMatrix> EvaluateMatrixExpr(const MatrixExpr& expr, MapTable& table,
                                             const ExpansionLimits& limits,
                                             std::vector<ExpansionStep>* report) {
  const size_t saved = table.max_maps();
  Expander x(table, limits, report);
  absl::StatusOr<IfsMatrix> r = x.Eval(expr, 0);
  table.set_max_maps(std::max(saved, table.size()));
  return r;
}

absl::Status MatrixCatalog::Add(std::string name, IfsMatrix matrix) {
  if (name.empty()) return absl::InvalidArgumentError("an IFS matrix needs a name");
  if (leaves_.count(name))
    return absl::AlreadyExistsError(absl::StrCat("IFS matrix ", Quoted(name), " is defined twice"));
  MatrixExprPtr leaf = MatrixLeaf(name, std::move(matrix));
  leaves_.emplace(std::move(name), std::move(leaf));
  return absl::OkStatus();
}

absl::StatusOr<MatrixExprPtr> MatrixCatalog::Find(std::string_view name) const {
  if (auto it = leaves_.find(name); it != leaves_.end()) return it->second;
  std::vector<std::string_view> names;
  for (const auto& [n, e] : leaves_) names.push_back(n);
  return absl::NotFoundError(
      absl::StrCat("unknown IFS matrix ", Quoted(name), "; defined matrices: ", NameList(names)));
}

}  // namespace nimbus
