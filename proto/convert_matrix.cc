// Converts chaos_game.matrices: named maps and matrices, expressions over
// them, the selection and the probabilities, into an expanded IFS matrix,
// a MarkovChain for the engine and an IfsMatrixPlan for the runner.

#include <cmath>
#include <map>
#include <set>

#include "absl/strings/str_join.h"
#include "core/matrix/ifs_matrix_plan.h"
#include "proto/convert_internal.h"

namespace nimbus::spec::internal {
namespace {

constexpr char kPath[] = "chaos_game.matrices";

// Keeps the code of a core error and prefixes the field path to its text.
absl::Status AtPath(const absl::Status& st, const std::string& path) {
  return absl::Status(st.code(), StrCat(path, ": ", std::string(st.message())));
}

std::string KnownNames(const std::map<std::string, MatrixExprPtr, std::less<>>& names) {
  std::vector<std::string> out;
  for (const auto& [name, expr] : names) out.push_back(name);
  return out.empty() ? "none" : absl::StrJoin(out, ", ");
}

// Matrices and named expressions visible to an expression being converted.
using Scope = std::map<std::string, MatrixExprPtr, std::less<>>;

absl::StatusOr<MatrixExprPtr> ConvertExpr(const v1::MatrixExpression& e, const std::string& path,
                                          const Scope& scope);

absl::StatusOr<std::vector<MatrixExprPtr>> ConvertOperands(const v1::MatrixOperands& ops,
                                                           const std::string& path,
                                                           const Scope& scope) {
  if (ops.operands_size() < 2)
    return Invalid(path + ".operands",
                   StrCat("needs at least 2 operands, got ", ops.operands_size()));
  std::vector<MatrixExprPtr> out;
  for (int i = 0; i < ops.operands_size(); ++i) {
    auto e = ConvertExpr(ops.operands(i), StrCat(path, ".operands[", i, "]"), scope);
    if (!e.ok()) return e.status();
    out.push_back(*std::move(e));
  }
  return out;
}

absl::StatusOr<MatrixExprPtr> ConvertExpr(const v1::MatrixExpression& e, const std::string& path,
                                          const Scope& scope) {
  MatrixExprPtr out;
  using V = v1::MatrixExpression;
  switch (e.op_case()) {
    case V::kMatrix: {
      auto it = scope.find(e.matrix());
      if (it == scope.end())
        return Invalid(path + ".matrix", StrCat("unknown matrix or expression '", e.matrix(),
                                                "' (known: ", KnownNames(scope), ")"));
      out = it->second;
      break;
    }
    case V::kConcatenationOf: {
      const v1::MatrixConcatenation& c = e.concatenation_of();
      if (!c.has_first() || !c.has_second())
        return Invalid(path + ".concatenation_of", "needs first and second");
      auto a = ConvertExpr(c.first(), path + ".concatenation_of.first", scope);
      if (!a.ok()) return a.status();
      auto b = ConvertExpr(c.second(), path + ".concatenation_of.second", scope);
      if (!b.ok()) return b.status();
      std::vector<MatrixLink> links;
      for (const v1::MatrixLink& l : c.links()) links.push_back({l.from(), l.to()});
      out = MatrixConcatenation(*a, *b, std::move(links));
      break;
    }
    case V::kUnionOf:
    case V::kIntersectionOf:
    case V::kCompositionOf:
    case V::kTensorProductOf:
    case V::kTensorSumOf:
    case V::kBlockOf: {
      const char* field = "";
      const v1::MatrixOperands* ops = nullptr;
      switch (e.op_case()) {
        case V::kUnionOf:
          field = ".union_of";
          ops = &e.union_of();
          break;
        case V::kIntersectionOf:
          field = ".intersection_of";
          ops = &e.intersection_of();
          break;
        case V::kCompositionOf:
          field = ".composition_of";
          ops = &e.composition_of();
          break;
        case V::kTensorProductOf:
          field = ".tensor_product_of";
          ops = &e.tensor_product_of();
          break;
        case V::kTensorSumOf:
          field = ".tensor_sum_of";
          ops = &e.tensor_sum_of();
          break;
        default:
          field = ".block_of";
          ops = &e.block_of();
          break;
      }
      auto operands = ConvertOperands(*ops, path + field, scope);
      if (!operands.ok()) return operands.status();
      switch (e.op_case()) {
        case V::kUnionOf:
          out = MatrixUnion(*std::move(operands));
          break;
        case V::kIntersectionOf:
          out = MatrixIntersection(*std::move(operands));
          break;
        case V::kCompositionOf:
          out = MatrixComposition(*std::move(operands));
          break;
        case V::kBlockOf:
          out = MatrixBlockDiagonal(*std::move(operands));
          break;
        default: {
          // Binary in the core; both products are associative, so fold left.
          const bool product = e.op_case() == V::kTensorProductOf;
          out = (*operands)[0];
          for (size_t i = 1; i < operands->size(); ++i)
            out = product ? MatrixTensorProduct(out, (*operands)[i])
                          : MatrixTensorSum(out, (*operands)[i]);
        }
      }
      break;
    }
    case V::OP_NOT_SET:
      return Invalid(path,
                     "empty expression: set one of matrix, union_of, intersection_of, "
                     "composition_of, tensor_product_of, tensor_sum_of, block_of, "
                     "concatenation_of");
  }
  if (!e.label().empty()) out = MatrixLabeled(e.label(), out);
  return out;
}

std::string SizeLine(const ExpansionStep& s) {
  return StrCat(s.expression, ": ", s.size, "x", s.size, ", ", s.map_references, " map references");
}

// --- Sections of ConvertMatrixChaosGame, in order ------------------------

// The named base maps. Expanding ones are refused unless allowed.
absl::StatusOr<std::vector<PointMap>> ConvertBaseMaps(const v1::IfsMatrixSystem& ms,
                                                      const Limits& limits, JobPlan& job) {
  const std::string path = kPath;
  if (ms.maps_size() == 0) return Invalid(path + ".maps", "needs at least one map");
  if (ms.maps_size() > limits.max_maps)
    return absl::ResourceExhaustedError(StrCat(
        path, ".maps: ", ms.maps_size(), " maps exceed the server limit of ", limits.max_maps));
  std::vector<PointMap> base;
  std::map<std::string, int> map_index;
  std::vector<std::string> expanding;
  for (int i = 0; i < ms.maps_size(); ++i) {
    const std::string mpath = StrCat(path, ".maps[", i, "]");
    if (ms.maps(i).name().empty())
      return Invalid(mpath + ".name", "required: matrices refer to maps by name");
    if (auto [it, fresh] = map_index.emplace(ms.maps(i).name(), i); !fresh)
      return Invalid(mpath + ".name", StrCat("duplicate map name '", ms.maps(i).name(),
                                             "' (also maps[", it->second, "])"));
    NIMBUS_ASSIGN_OR_RETURN(PointMap m, ConvertMap(ms.maps(i), mpath));
    const double factor = m.pre.ContractionFactor();
    if (m.IsAffine() && factor >= 1.0) {
      char buf[64];
      std::snprintf(buf, sizeof buf, "%.4g", factor);
      expanding.push_back(StrCat(mpath, " '", m.name, "' (factor ", buf, ")"));
    }
    const double p = ms.maps(i).probability();
    if (!(p >= 0) || !std::isfinite(p))
      return Invalid(mpath + ".probability", "must be finite and >= 0");
    base.push_back(std::move(m));
  }
  if (!expanding.empty()) {
    const std::string msg =
        StrCat("not a contraction: ", absl::StrJoin(expanding, ", "),
               "; the chaos game needs every map's largest singular value below 1");
    if (!ms.allow_expanding())
      return Invalid(path + ".maps",
                     StrCat(msg, " (set ", path, ".allow_expanding to run anyway)"));
    job.warnings.push_back(msg);
  }
  return base;
}

// One matrix definition: rows of entries naming maps of `table`.
absl::StatusOr<IfsMatrix> ConvertMatrixDef(const v1::IfsMatrixDef& def, const std::string& mpath,
                                           const MapTable& table, const ExpansionLimits& limits) {
  const int n = def.rows_size();
  if (n == 0) return Invalid(mpath + ".rows", "needs at least one row");
  if (uint32_t(n) > limits.max_size)
    return absl::ResourceExhaustedError(
        StrCat(mpath, ".rows: ", n, " rows exceed the limit of ", limits.max_size));
  IfsMatrix matrix{uint32_t(n)};
  for (int i = 0; i < n; ++i) {
    const v1::MatrixRow& row = def.rows(i);
    const std::string rpath = StrCat(mpath, ".rows[", i, "]");
    if (row.entries_size() != n)
      return Invalid(rpath + ".entries",
                     StrCat("matrix '", def.name(), "' has ", n, " rows, so every row needs ", n,
                            " entries; got ", row.entries_size()));
    for (int j = 0; j < n; ++j) {
      const v1::MatrixEntry& entry = row.entries(j);
      for (int k = 0; k < entry.maps_size(); ++k) {
        auto index = table.Find(entry.maps(k));
        if (!index.ok())
          return Invalid(StrCat(rpath, ".entries[", j, "].maps[", k, "]"),
                         StrCat("unknown map '", entry.maps(k), "' in matrix '", def.name(),
                                "' (", std::string(index.status().message()), ")"));
        matrix.Insert(uint32_t(i), uint32_t(j), *index);
      }
    }
  }
  return matrix;
}

absl::Status ConvertMatrixDefs(const v1::IfsMatrixSystem& ms, const MapTable& table,
                               const ExpansionLimits& limits, Scope& scope) {
  for (int m = 0; m < ms.matrices_size(); ++m) {
    const v1::IfsMatrixDef& def = ms.matrices(m);
    const std::string mpath = StrCat(kPath, ".matrices[", m, "]");
    if (def.name().empty()) return Invalid(mpath + ".name", "required");
    if (scope.count(def.name()))
      return Invalid(mpath + ".name", StrCat("duplicate matrix name '", def.name(), "'"));
    NIMBUS_ASSIGN_OR_RETURN(IfsMatrix matrix, ConvertMatrixDef(def, mpath, table, limits));
    scope.emplace(def.name(), MatrixLeaf(def.name(), std::move(matrix)));
  }
  return absl::OkStatus();
}

// Named expressions, checked and sized one by one on a scratch table: only
// the render expression's maps go to the engine, but every step is reported.
absl::Status ConvertNamedExpressions(const v1::IfsMatrixSystem& ms, const MapTable& table,
                                     const ExpansionLimits& limits, Scope& scope,
                                     IfsMatrixPlan& plan, std::vector<std::string>& sizes) {
  for (int x = 0; x < ms.expressions_size(); ++x) {
    const v1::NamedMatrixExpression& named = ms.expressions(x);
    const std::string xpath = StrCat(kPath, ".expressions[", x, "]");
    if (named.name().empty()) return Invalid(xpath + ".name", "required");
    if (scope.count(named.name()))
      return Invalid(xpath + ".name",
                     StrCat("duplicate matrix or expression name '", named.name(), "'"));
    if (!named.has_expression()) return Invalid(xpath + ".expression", "required");
    NIMBUS_ASSIGN_OR_RETURN(MatrixExprPtr expr,
                            ConvertExpr(named.expression(), xpath + ".expression", scope));
    MatrixExprPtr labelled = MatrixLabeled(named.name(), expr);
    MapTable scratch = table;
    std::vector<ExpansionStep> report;
    auto value = EvaluateMatrixExpr(*labelled, scratch, limits, &report);
    if (!value.ok()) return AtPath(value.status(), xpath + ".expression");
    sizes.push_back(SizeLine(report.back()));
    plan.expansion.push_back(report.back());
    scope.emplace(named.name(), std::move(labelled));
  }
  return absl::OkStatus();
}

// The rendered matrix, expanded into `table`.
struct Rendered {
  IfsMatrix matrix;
  std::string name;
  BoolMatrix limit;  // components non-empty in the limit
};

absl::StatusOr<Rendered> ConvertRender(const v1::IfsMatrixSystem& ms, MapTable& table,
                                       const ExpansionLimits& limits, const Scope& scope,
                                       IfsMatrixPlan& plan, std::vector<std::string>& sizes,
                                       JobPlan& job) {
  const std::string path = kPath;
  if (!ms.has_render())
    return Invalid(path + ".render",
                   "required: the expression to render, e.g. {\"matrix\": "
                   "\"<name>\"}");
  NIMBUS_ASSIGN_OR_RETURN(MatrixExprPtr render, ConvertExpr(ms.render(), path + ".render", scope));
  const std::string render_name = DescribeMatrixExpr(*render);
  std::vector<ExpansionStep> report;
  auto matrix = EvaluateMatrixExpr(*render, table, limits, &report);
  if (!matrix.ok()) return AtPath(matrix.status(), path + ".render");
  plan.expansion.push_back(report.back());
  sizes.push_back(StrCat("render = ", SizeLine(report.back())));
  job.warnings.push_back(StrCat("info: expanded IFS matrices: ", absl::StrJoin(sizes, "; "),
                                "; map table ", table.size(), " maps"));
  auto limit = AperiodicLimitPattern(*matrix, render_name);
  if (!limit.ok()) return AtPath(limit.status(), path + ".render");
  return Rendered{*std::move(matrix), render_name, *std::move(limit)};
}

absl::Status SelectByComponents(const v1::IfsMatrixSystem& ms, const Rendered& r,
                                std::vector<Component>& selection) {
  const uint32_t n = r.matrix.size();
  std::set<std::pair<uint32_t, uint32_t>> seen;
  for (int k = 0; k < ms.components_size(); ++k) {
    const v1::MatrixComponent& c = ms.components(k);
    const std::string cpath = StrCat(kPath, ".components[", k, "]");
    if (c.row() >= n || c.col() >= n)
      return Invalid(cpath, StrCat("component (", c.row(), ", ", c.col(), ") is outside the ", n,
                                   "x", n, " matrix ", r.name, " (indices are 0-based)"));
    if (!r.limit.Get(c.row(), c.col()))
      return Invalid(cpath, StrCat("component (", c.row(), ", ", c.col(), ") of ", r.name,
                                   " is empty: no path of every length leads from state ",
                                   c.row(), " to state ", c.col()));
    if (!seen.emplace(c.row(), c.col()).second)
      return Invalid(cpath, StrCat("component (", c.row(), ", ", c.col(), ") is selected twice"));
    selection.push_back({c.row(), c.col()});
  }
  return absl::OkStatus();
}

absl::Status CheckStates(const google::protobuf::RepeatedField<uint32_t>& states,
                         const std::string& field, const Rendered& r) {
  const uint32_t n = r.matrix.size();
  std::set<uint32_t> seen;
  for (int k = 0; k < states.size(); ++k) {
    if (states[k] >= n)
      return Invalid(StrCat(kPath, ".", field, "[", k, "]"),
                     StrCat("state ", states[k], " is outside the ", n, "x", n, " matrix ",
                            r.name, " (states are 0-based)"));
    if (!seen.insert(states[k]).second)
      return Invalid(StrCat(kPath, ".", field, "[", k, "]"),
                     StrCat("state ", states[k], " is listed twice"));
  }
  return absl::OkStatus();
}

absl::Status SelectByStates(const v1::IfsMatrixSystem& ms, const Rendered& r,
                            std::vector<Component>& selection) {
  const std::string path = kPath;
  if (ms.initial_states_size() == 0 || ms.final_states_size() == 0)
    return Invalid(path + (ms.initial_states_size() == 0 ? ".initial_states" : ".final_states"),
                   "give both initial_states and final_states");
  NIMBUS_RETURN_IF_ERROR(CheckStates(ms.initial_states(), "initial_states", r));
  NIMBUS_RETURN_IF_ERROR(CheckStates(ms.final_states(), "final_states", r));
  for (uint32_t i : ms.initial_states())
    for (uint32_t j : ms.final_states())
      if (r.limit.Get(i, j)) selection.push_back({i, j});
  if (selection.empty())
    return Invalid(path + ".final_states",
                   StrCat("every component from initial_states to final_states of ", r.name,
                          " is empty"));
  return absl::OkStatus();
}

absl::Status SelectComponents(const v1::IfsMatrixSystem& ms, const Rendered& r,
                              std::vector<Component>& selection) {
  const bool by_states = ms.initial_states_size() > 0 || ms.final_states_size() > 0;
  if (by_states == (ms.components_size() > 0))
    return Invalid(std::string(kPath) + ".components",
                   "select components either by components or by initial_states and "
                   "final_states (exactly one way)");
  return by_states ? SelectByStates(ms, r, selection) : SelectByComponents(ms, r, selection);
}

// How maps are drawn: the floor and, in explicit mode, a weight per table
// map (empty in determinant mode).
struct Drawing {
  double floor = 0.01;
  bool explicit_mode = false;
  std::vector<double> weights;
};

absl::StatusOr<Drawing> ConvertDrawing(const v1::IfsMatrixSystem& ms, const MapTable& table) {
  const std::string path = kPath;
  Drawing d;
  d.floor = ms.probability_floor();
  if (!(d.floor >= 0 && d.floor <= 1))
    return Invalid(path + ".probability_floor", "must be in [0, 1]");
  if (d.floor == 0) d.floor = 0.01;
  NIMBUS_RETURN_IF_ERROR(CheckProbabilityMode(ms.probability_mode(), path + ".probability_mode"));
  v1::ProbabilityMode mode = ms.probability_mode();
  if (mode == v1::PROBABILITY_MODE_UNSPECIFIED) {
    // As for a plain IFS: explicit when every map gives a probability.
    bool all_set = true;
    for (const auto& m : ms.maps()) all_set &= m.probability() > 0;
    mode = all_set ? v1::PROBABILITY_MODE_EXPLICIT : v1::PROBABILITY_MODE_DETERMINANT;
  }
  d.explicit_mode = mode == v1::PROBABILITY_MODE_EXPLICIT;
  if (!d.explicit_mode) return d;
  for (int i = 0; i < ms.maps_size(); ++i)
    if (!(ms.maps(i).probability() > 0))
      return Invalid(StrCat(path, ".maps[", i, "].probability"),
                     "explicit mode needs every map's probability > 0");
  // A composed map is drawn where its factors would have been drawn in
  // turn, so it gets the product of their weights.
  for (uint32_t t = 0; t < table.size(); ++t) {
    double w = 1;
    for (uint32_t letter : table.word(t)) w *= ms.maps(int(letter)).probability();
    // Products of large weights can overflow; explicit weights are relative,
    // so a finite product is all the chain needs.
    if (!std::isfinite(w))
      return Invalid(path + ".maps",
                     StrCat("the product of the probabilities of composed map ", t,
                            " overflows; use smaller explicit probabilities"));
    d.weights.push_back(w);
  }
  return d;
}

ComponentChainOptions ChainOptions(const Drawing& d) {
  ComponentChainOptions o;
  o.probability_floor = d.floor;
  o.map_weights = d.weights;
  return o;
}

// The run of the whole selection: a plain IFS for a 1x1 matrix (the same
// maps, order and probabilities as the equivalent ifs spec, so the same
// seed gives the same volume bit for bit), a chain otherwise.
absl::Status BuildWholeRun(const Rendered& r, const MapTable& table, const Drawing& d,
                           IfsMatrixPlan& plan) {
  ChaosGameParams& params = plan.run;
  if (r.matrix.size() == 1) {
    const IfsMatrix::Entry& entry = r.matrix.at(0, 0);
    for (uint32_t t : entry) params.ifs.maps.push_back(table.map(t));
    if (d.explicit_mode) {
      double total = 0;
      for (uint32_t t : entry) total += d.weights[t];
      for (uint32_t t : entry) params.ifs.probabilities.push_back(d.weights[t] / total);
    } else {
      params.ifs.probabilities = DeterminantProbabilities(params.ifs.maps, d.floor);
    }
    plan.chain_states = 0;
    return absl::OkStatus();
  }
  auto chain = BuildComponentChain(table.maps(), r.matrix, plan.selection, r.name, ChainOptions(d));
  if (!chain.ok()) return AtPath(chain.status(), std::string(kPath) + ".render");
  params.ifs.maps = table.maps();
  // Unused with a chain, but the engine validates them.
  params.ifs.probabilities.assign(params.ifs.maps.size(), 1.0 / double(params.ifs.maps.size()));
  params.chain = std::move(chain->chain);
  plan.chain_states = params.chain->states.size();
  return absl::OkStatus();
}

absl::Status ConvertComponentGrid(const v1::ChaosGame& cg, IfsMatrixPlan& plan) {
  switch (cg.matrices().component_grid()) {
    case v1::COMPONENT_GRID_NONE: plan.component_grid = ComponentGridType::kNone; break;
    case v1::COMPONENT_GRID_INT: plan.component_grid = ComponentGridType::kInt; break;
    case v1::COMPONENT_GRID_FLOAT: plan.component_grid = ComponentGridType::kFloat; break;
    default: return Invalid(std::string(kPath) + ".component_grid", "unknown value");
  }
  if (plan.component_grid == ComponentGridType::kNone) return absl::OkStatus();
  // Component runs are summed and labelled by count; these options would
  // be silently lost there, so they are refused by name.
  const char* why = "not supported together with chaos_game.matrices.component_grid";
  if (cg.has_color()) return Invalid("chaos_game.color", why);
  if (cg.has_convergence()) return Invalid("chaos_game.convergence", why);
  if (cg.splat()) return Invalid("chaos_game.splat", why);
  return absl::OkStatus();
}

// With a component grid: one run per selected component, iterations split
// evenly, distinct streams per component (component 0 keeps the seed).
absl::Status BuildComponentRuns(const v1::ChaosGame& cg, const Rendered& r, const MapTable& table,
                                const Drawing& d, IfsMatrixPlan& plan) {
  const uint64_t k = plan.selection.size();
  if (cg.iterations() < k)
    return Invalid("chaos_game.iterations",
                   StrCat("a component grid needs at least one iteration per selected "
                          "component (",
                          k, ")"));
  for (uint64_t c = 0; c < k; ++c) {
    ChaosGameParams run = plan.run;
    run.iterations = cg.iterations() / k + (c < cg.iterations() % k ? 1 : 0);
    run.seed = cg.seed() + c * 0x9E3779B97F4A7C15ull;
    if (r.matrix.size() > 1) {
      auto chain = BuildComponentChain(table.maps(), r.matrix, {plan.selection[c]}, r.name,
                                       ChainOptions(d));
      if (!chain.ok()) return AtPath(chain.status(), StrCat(kPath, ".components"));
      run.chain = std::move(chain->chain);
    }
    plan.component_runs.push_back(std::move(run));
  }
  return absl::OkStatus();
}

}  // namespace

absl::Status ConvertMatrixChaosGame(const v1::ChaosGame& cg, const Limits& limits,
                                    JobPlan& job) {
  const v1::IfsMatrixSystem& ms = cg.matrices();
  IfsMatrixPlan plan;
  NIMBUS_ASSIGN_OR_RETURN(std::vector<PointMap> base, ConvertBaseMaps(ms, limits, job));
  const ExpansionLimits expansion_limits;
  MapTable table(base);
  table.set_max_maps(expansion_limits.max_table_maps);
  Scope scope;
  NIMBUS_RETURN_IF_ERROR(ConvertMatrixDefs(ms, table, expansion_limits, scope));
  std::vector<std::string> sizes;
  NIMBUS_RETURN_IF_ERROR(
      ConvertNamedExpressions(ms, table, expansion_limits, scope, plan, sizes));
  NIMBUS_ASSIGN_OR_RETURN(Rendered rendered,
                          ConvertRender(ms, table, expansion_limits, scope, plan, sizes, job));
  NIMBUS_RETURN_IF_ERROR(SelectComponents(ms, rendered, plan.selection));
  NIMBUS_ASSIGN_OR_RETURN(Drawing drawing, ConvertDrawing(ms, table));
  NIMBUS_RETURN_IF_ERROR(CheckIterations(cg, limits));
  ChaosGameParams& params = plan.run;
  params.frame = job.frame;
  params.iterations = cg.iterations();
  params.warmup = cg.warmup() == 0 ? 100 : cg.warmup();
  params.seed = cg.seed();
  // Colour, raw counts, convergence and splatting mean what they mean for a
  // plain IFS: the chain walks the same engine.
  NIMBUS_RETURN_IF_ERROR(ConvertEngineOptions(cg, params, job.density));
  NIMBUS_RETURN_IF_ERROR(BuildWholeRun(rendered, table, drawing, plan));
  for (const PointMap& m : params.ifs.maps)
    job.contraction_factors.push_back(m.pre.ContractionFactor());
  NIMBUS_RETURN_IF_ERROR(ConvertComponentGrid(cg, plan));
  if (plan.component_grid != ComponentGridType::kNone) {
    // Labels have no meaningful box filter.
    const OutputConventions& c = job.density.conventions;
    const char* why = "not supported together with chaos_game.matrices.component_grid";
    if (c.max_voxels > 0) return Invalid("output.max_voxels", why);
    if (c.target_file_bytes > 0) return Invalid("output.target_file_bytes", why);
    NIMBUS_RETURN_IF_ERROR(BuildComponentRuns(cg, rendered, table, drawing, plan));
  }
  plan.maps = table.maps();
  plan.matrix = std::move(rendered.matrix);
  job.work = {cg.iterations(), "points"};
  job.kind = std::move(plan);
  return absl::OkStatus();
}

}  // namespace nimbus::spec::internal
