// IFS matrices (recurrent, graph-directed IFS) and the constructive
// operations that combine them (ALGORITHMS.md section 4; docs/ifs_matrices.md).
//
// Conventions used throughout:
//  * indices are 0-based (the seed counts from 1: its A_12 is our (0, 1));
//  * an entry H_ij is a sorted set of indices into a shared map table;
//  * "f after g" is written f o g and means f(g(p)), as in Affine3;
//  * component (i, j) of the attractor matrix is
//      A_ij = lim_{m->inf} (H^m)_ij (K),  (H^m)_ij = { f1 o ... o fm : f1 in
//      H_{i k1}, f2 in H_{k1 k2}, ..., fm in H_{k(m-1) j} },
//    i.e. the limit of images under words read along graph paths i -> j.
#pragma once

#include <cstdint>
#include <map>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/chaos/chaos_game.h"
#include "core/grid/count_grid.h"
#include "core/base/geometry.h"
#include "core/base/interrupter.h"
#include "core/chaos/point_map.h"

namespace nimbus {

// ---------------------------------------------------------------------------
// Map table
// ---------------------------------------------------------------------------

/// @brief The growing, append-only table of point maps that IFS matrices
/// index. Every entry carries its *word*: the sequence of base maps it is
/// the composition of (outermost first; the identity map has the empty
/// word). Composition is memoised by word, so f o (g o h) and (f o g) o h
/// share one entry and set operations on entries compare words, not floats.
///
/// Composition is concrete (a new PointMap the engine can run), not
/// symbolic, and therefore restricted to what a PointMap can express
/// exactly: the OUTER map f must have no variations (it may have a post
/// affine, which then just folds in). Affine after affine multiplies the
/// affines; affine after nonlinear g becomes g with f folded into g's post.
/// Nonlinear after anything is refused, naming the map, because variations
/// read their own pre-affine's coefficients and cannot absorb an inner map.
class MapTable {
 public:
  MapTable() = default;
  /// The base maps get the one-letter words {0}, {1}, ...
  explicit MapTable(std::vector<PointMap> base_maps);

  size_t size() const { return maps_.size(); }
  size_t base_size() const { return base_size_; }
  const std::vector<PointMap>& maps() const { return maps_; }
  const PointMap& map(uint32_t index) const { return maps_[index]; }
  /// Base-map letters of entry `index`, outermost first.
  const std::vector<uint32_t>& word(uint32_t index) const { return words_[index]; }
  bool IsIdentity(uint32_t index) const { return words_[index].empty(); }

  /// Index of the first map called `name`; NotFound lists the known names.
  absl::StatusOr<uint32_t> Find(std::string_view name) const;

  /// Index of the identity map (named "identity"), appended on first use.
  absl::StatusOr<uint32_t> Identity();

  /// Index of f o g (f after g), appending it unless its word exists.
  /// Identity is neutral. Errors: OutOfRange for a bad index,
  /// InvalidArgument when f is nonlinear, ResourceExhausted beyond
  /// max_maps().
  absl::StatusOr<uint32_t> Compose(uint32_t f, uint32_t g);

  void set_max_maps(size_t max_maps) { max_maps_ = max_maps; }
  size_t max_maps() const { return max_maps_; }

 private:
  absl::StatusOr<uint32_t> Append(PointMap map, std::vector<uint32_t> word);

  std::vector<PointMap> maps_;
  std::vector<std::vector<uint32_t>> words_;
  std::map<std::vector<uint32_t>, uint32_t> by_word_;
  size_t base_size_ = 0;
  size_t max_maps_ = size_t{1} << 16;
};

// ---------------------------------------------------------------------------
// Matrices
// ---------------------------------------------------------------------------

/// A cell of an IFS matrix (and a component of its attractor matrix).
struct Component {
  uint32_t row = 0;
  uint32_t col = 0;
  friend bool operator==(Component a, Component b) = default;
};

/// @brief An n x n matrix whose entries are finite, possibly empty, sets of
/// map-table indices, kept sorted and free of duplicates.
class IfsMatrix {
 public:
  using Entry = std::vector<uint32_t>;

  IfsMatrix() = default;
  explicit IfsMatrix(uint32_t n) : n_(n), entries_(size_t{n} * n) {}
  /// Square rows of entries; InvalidArgument if not square.
  static absl::StatusOr<IfsMatrix> FromRows(const std::vector<std::vector<Entry>>& rows);

  uint32_t size() const { return n_; }
  const Entry& at(uint32_t i, uint32_t j) const { return entries_[size_t{i} * n_ + j]; }
  bool empty(uint32_t i, uint32_t j) const { return at(i, j).empty(); }
  /// Replaces an entry (sorted and de-duplicated here).
  void Set(uint32_t i, uint32_t j, Entry maps);
  void Insert(uint32_t i, uint32_t j, uint32_t map);
  /// Sum of entry sizes: the matrix's cost measure.
  uint64_t MapReferences() const;

  friend bool operator==(const IfsMatrix&, const IfsMatrix&) = default;

 private:
  uint32_t n_ = 0;
  std::vector<Entry> entries_;  // row-major
};

/// OK iff every index of `m` is in `table`; otherwise InvalidArgument naming
/// the matrix, the cell and the index.
absl::Status ValidateMatrix(const IfsMatrix& m, size_t table_size, std::string_view name);

/// @brief A square boolean matrix stored as 64-bit row words, for the
/// pattern R of non-empty entries and its powers.
class BoolMatrix {
 public:
  BoolMatrix() = default;
  explicit BoolMatrix(uint32_t n) : n_(n), words_((n + 63) / 64), bits_(size_t{n} * words_) {}
  static BoolMatrix PatternOf(const IfsMatrix& m);

  uint32_t size() const { return n_; }
  bool Get(uint32_t i, uint32_t j) const {
    return (bits_[size_t{i} * words_ + j / 64] >> (j % 64)) & 1;
  }
  void Set(uint32_t i, uint32_t j, bool v = true);
  /// Boolean product: (A B)_ij = OR_k A_ik AND B_kj.
  friend BoolMatrix operator*(const BoolMatrix& a, const BoolMatrix& b);
  friend bool operator==(const BoolMatrix&, const BoolMatrix&) = default;

 private:
  uint32_t n_ = 0;
  uint32_t words_ = 0;
  std::vector<uint64_t> bits_;
};

// ---------------------------------------------------------------------------
// Aperiodicity and the limit pattern
// ---------------------------------------------------------------------------

/// Where the powers R, R^2, R^3, ... of a boolean matrix settle.
struct PowerAnalysis {
  /// R^k for every k >= index (meaningful when aperiodic).
  BoolMatrix limit;
  /// Smallest m with R^m == R^(m+1) (aperiodic only), else 0.
  uint64_t index = 0;
  /// Cycle length of the power sequence; 1 = aperiodic; 0 = longer than the
  /// search cap (certainly periodic).
  uint64_t period = 1;
  bool aperiodic() const { return period == 1; }
};

/// @brief Finds the cycle the powers of R fall into. The sequence is
/// eventually periodic and its transient (index) is at most (n-1)^2 + 1
/// for any n x n boolean matrix, so R^K with K = n^2 + 1 (reached by
/// repeated squaring) is already on the cycle; the cycle length is then the
/// first t with R^(K+t) == R^K, and aperiodicity is R^(K+1) == R^K.
PowerAnalysis AnalyzePowers(const BoolMatrix& r);

/// The limit pattern lim R^k of an aperiodic matrix: (i, j) set iff the
/// component A_ij is non-empty. InvalidArgument naming `name` (and the
/// period) when the matrix is not aperiodic, or has size 0.
absl::StatusOr<BoolMatrix> AperiodicLimitPattern(const IfsMatrix& m, std::string_view name);
/// Same check, status only.
absl::Status CheckAperiodic(const IfsMatrix& m, std::string_view name);

/// OK iff `selection` is non-empty and every component is in range and
/// non-empty in `limit`; InvalidArgument naming the matrix and component.
absl::Status CheckSelection(const BoolMatrix& limit, const std::vector<Component>& selection,
                            std::string_view name);

// ---------------------------------------------------------------------------
// Expressions
// ---------------------------------------------------------------------------

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

// ---------------------------------------------------------------------------
// Rendering support
// ---------------------------------------------------------------------------

struct DeterministicRenderOptions {
  Vec3 start;  // K: the point every word is applied to
  uint64_t max_points = uint64_t{1} << 22;
  uint64_t seed = 0;  // for random variations only
};

/// @brief Deterministic algorithm for one component: applies every word of
/// (H^depth)_ij (all paths i -> j of exactly `depth` edges) to the start
/// point, innermost map first. Computed backwards from j, keeping only rows
/// that row i reaches in the remaining number of steps, so every
/// intermediate point ends up in the output. ResourceExhausted when the
/// word count exceeds max_points (checked before any map is applied).
absl::StatusOr<std::vector<Vec3>> RenderComponentDeterministic(
    const std::vector<PointMap>& maps, const IfsMatrix& m, Component c, int depth,
    const DeterministicRenderOptions& options = {});

struct ComponentChainOptions {
  /// Determinant rule: a transition's weight is |det pre| of its map, raised
  /// to at least floor * (largest |det| among the matrix's maps).
  double probability_floor = 0.01;
  /// Optional explicit weights by map-table index (all > 0); overrides the
  /// determinant rule when non-empty.
  std::vector<double> map_weights;
  /// Unplotted steps inside a sink class after every (re)start; 0 = derived
  /// from the contraction: ceil(log(warmup_tolerance) / log(c_max)).
  uint32_t warmup_steps = 0;
  double warmup_tolerance = 1e-5;
  /// Used when c_max is unknown (nonlinear maps) or >= 1.
  uint32_t fallback_warmup_steps = 64;
  /// Per-step chance of a restart from states that need one; 0 = 1 / (2 L)
  /// for the longest warm-up L.
  double restart_probability = 0;
  /// ResourceExhausted beyond this many chain states.
  size_t max_states = size_t{1} << 20;
};

/// @brief A MarkovChain for a selection of components plus, per chain
/// state, where it comes from.
struct ComponentChain {
  enum class Kind {
    kLive,     // a matrix state of a column block; plotted iff selected
    kWarmup,   // unplotted copy of a sink-class state, `level` steps in
    kRestart,  // unplotted hub that picks the sink class to re-enter
  };
  struct StateInfo {
    Kind kind = Kind::kLive;
    uint32_t row = 0;    // matrix state (live and warm-up states)
    uint32_t col = 0;    // column j of the block (live and warm-up states)
    uint32_t level = 0;  // warm-up copies only
  };
  MarkovChain chain;
  std::vector<StateInfo> states;  // parallel to chain.states
};

/// @brief Builds the chaos game on the graph for `selection` (labels are
/// selection indices).
///
/// Why backwards: a point of A_sj is refined by prepending a map, f(A_sj)
/// is part of A_rj for f in H_rs. So a walker holding (p, s) draws a
/// predecessor edge r -> s with map f, sets p = f(p) and moves to r. After
/// many steps p is f1 o ... o fm (p0) for a path r -> ... -> s0, whose
/// prefix is what fixes the point.
///
/// Construction, one block per selected column j:
///  * live states: S_j = { r : lim R^k has (r, j) } (rows whose component
///    in column j exists), further restricted to the states a selected row
///    reaches (others never lead back to a plotted state). Each has every
///    predecessor edge inside the block as a transition, weighted by the
///    map weight and normalised per state. Plotted iff (r, j) is selected.
///  * warm-up: the walk's tail is its innermost part, and any infinite path
///    in S_j can be approximated by one that ends in a *sink* strongly
///    connected class of the block. So every (re)start enters L unplotted
///    copies of a sink class (walking only its internal edges) and then its
///    live states; L is chosen so c_max^L < warmup_tolerance.
///  * restarts: walking backwards the walker drifts to source-side classes
///    and would stay there (e.g. the tree's canopy state), so live states
///    outside sink classes, states without predecessors, and every live
///    state when there are several blocks restart with some probability
///    into a warm-up, sink classes chosen uniformly over all blocks (through
///    one hub state when there are several, to keep transitions few).
///  * the walk starts in the first warm-up, so it needs no engine warm-up.
///
/// Errors (InvalidArgument naming `name`): periodic matrix, empty or
/// out-of-range component, bad map index or weights.
absl::StatusOr<ComponentChain> BuildComponentChain(const std::vector<PointMap>& maps,
                                                   const IfsMatrix& m,
                                                   const std::vector<Component>& selection,
                                                   std::string_view name,
                                                   const ComponentChainOptions& options = {});

/// Counts from the reference chaos game.
struct ReferenceChaosResult {
  explicit ReferenceChaosResult(Int3 resolution) : counts(resolution) {}
  CountGrid counts;               // every plotted point
  std::vector<CountGrid> labels;  // by ChainState::label (labels >= 0)
  uint64_t plotted = 0;           // points counted (inside the frame)
  uint64_t outside = 0;
  uint64_t reseeded = 0;
};

/// @brief Single-threaded, unoptimised chaos game over a MarkovChain, with
/// the same step rule as the engine: draw a transition of the current
/// state, apply its map, move, then plot if the new state is plotted. The
/// walker starts at a random point of the frame in chain.start_state and
/// takes `warmup` unplotted steps first (and again after a non-finite
/// point). Used as ground truth by tests.
absl::StatusOr<ReferenceChaosResult> RunChainReference(const std::vector<PointMap>& maps,
                                                       const MarkovChain& chain,
                                                       const GridFrame& frame, uint64_t iterations,
                                                       uint32_t warmup, uint64_t seed,
                                                       Interrupter* interrupter = nullptr);

// ---------------------------------------------------------------------------
// Worked example
// ---------------------------------------------------------------------------

/// Maps and matrix of an example; maps are in table order.
struct IfsMatrixExample {
  std::vector<PointMap> maps;
  IfsMatrix matrix;
};

/// @brief The 3D tree of ALGORITHMS.md section 4: maps T1..T4 (indices
/// 0..3) and H = [[{T3, T4}, {T1, T2}], [{}, {T1, T2}]]. Component (1, 1)
/// is the trunk from (0,0,0) to (0,1,0), (0, 0) the canopy A(T3, T4), and
/// (0, 1) the branching tree.
IfsMatrixExample TreeMatrixExample();

}  // namespace nimbus
