#include "core/matrix/component_chain.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <string>
#include <utility>

#include "absl/strings/str_cat.h"
#include "core/base/status_macros.h"
#include "core/matrix/matrix_text.h"

namespace nimbus {
namespace {

using matrix_internal::AffineOf;
using matrix_internal::HasNoVariations;
using matrix_internal::Quoted;
using Kind = ComponentChain::Kind;

// Tarjan's strongly connected components, iterative. Returns the class id
// of every vertex.
std::vector<uint32_t> StronglyConnected(const BoolMatrix& g) {
  const uint32_t n = g.size();
  constexpr uint32_t kUnset = std::numeric_limits<uint32_t>::max();
  std::vector<uint32_t> index(n, kUnset), low(n, 0), comp(n, kUnset), stack;
  std::vector<char> on_stack(n, 0);
  struct Frame {
    uint32_t v, next;
  };
  std::vector<Frame> calls;
  uint32_t counter = 0, classes = 0;
  for (uint32_t root = 0; root < n; ++root) {
    if (index[root] != kUnset) continue;
    auto visit = [&](uint32_t v) {
      index[v] = low[v] = counter++;
      stack.push_back(v);
      on_stack[v] = 1;
      calls.push_back({v, 0});
    };
    visit(root);
    while (!calls.empty()) {
      const uint32_t v = calls.back().v;
      if (calls.back().next < n) {
        const uint32_t w = calls.back().next++;
        if (!g.Get(v, w)) continue;
        if (index[w] == kUnset) {
          visit(w);
        } else if (on_stack[w]) {
          low[v] = std::min(low[v], index[w]);
        }
        continue;
      }
      if (low[v] == index[v]) {
        uint32_t w;
        do {
          w = stack.back();
          stack.pop_back();
          on_stack[w] = 0;
          comp[w] = classes;
        } while (w != v);
        ++classes;
      }
      calls.pop_back();
      if (!calls.empty()) low[calls.back().v] = std::min(low[calls.back().v], low[v]);
    }
  }
  return comp;
}

// Per-map transition weights: the explicit ones, or the determinant rule
// over the maps the matrix uses.
absl::StatusOr<std::vector<double>> MapWeights(const std::vector<PointMap>& maps,
                                               const IfsMatrix& m, std::string_view name,
                                               const ComponentChainOptions& options) {
  std::vector<double> weight(maps.size(), 0.0);
  if (!options.map_weights.empty()) {
    if (options.map_weights.size() != maps.size())
      return absl::InvalidArgumentError(absl::StrCat("IFS matrix ", Quoted(name), ": ",
                                                     options.map_weights.size(),
                                                     " map weights for ", maps.size(), " maps"));
    for (size_t f = 0; f < maps.size(); ++f) {
      const double w = options.map_weights[f];
      if (!(w > 0) || !std::isfinite(w))
        return absl::InvalidArgumentError(absl::StrCat("IFS matrix ", Quoted(name),
                                                       ": the weight of map ", Quoted(maps[f].name),
                                                       " must be positive and finite"));
      weight[f] = w;
    }
    return weight;
  }
  double largest = 0;
  for (uint32_t i = 0; i < m.size(); ++i)
    for (uint32_t j = 0; j < m.size(); ++j)
      for (uint32_t f : m.at(i, j)) {
        weight[f] = std::fabs(maps[f].pre.Determinant());
        largest = std::max(largest, weight[f]);
      }
  if (!(largest > 0)) largest = 1;
  for (double& w : weight) w = std::max(w, options.probability_floor * largest);
  for (double& w : weight)
    if (!(w > 0)) w = 1;  // a zero floor on an all-degenerate matrix: uniform
  return weight;
}

// Warm-up length L with c_max^L < tolerance, when the contraction is known.
uint32_t DerivedWarmupSteps(const ComponentChainOptions& options, double c_max, bool unknown) {
  uint32_t steps;
  if (unknown || !(c_max < 1)) {
    steps = options.fallback_warmup_steps;
  } else if (c_max <= 0) {
    steps = 1;
  } else {
    const double l = std::ceil(std::log(options.warmup_tolerance) / std::log(c_max));
    steps = static_cast<uint32_t>(std::clamp(l, 1.0, 4096.0));
  }
  return std::max<uint32_t>(steps, 1);
}

// Builds the chain block by block (see BuildComponentChain in the header),
// then wires the restarts. State and transition order is part of the
// result: the engine's random stream depends on it.
class ChainBuilder {
 public:
  ChainBuilder(const std::vector<PointMap>& maps, const IfsMatrix& m, const BoolMatrix& limit,
               std::string_view name, const ComponentChainOptions& options,
               std::vector<double> weight)
      : maps_(maps),
        m_(m),
        r_(BoolMatrix::PatternOf(m)),
        limit_(limit),
        scc_(StronglyConnected(r_)),
        name_(name),
        options_(options),
        weight_(std::move(weight)) {}

  // One column block: its live states, their predecessor edges, and a
  // warm-up per sink class. `label` maps a selected (row, col) to its label.
  absl::Status AddBlock(uint32_t j, const std::vector<Component>& selection,
                        const std::map<std::pair<uint32_t, uint32_t>, int32_t>& label);

  // Restarts, normalisation and the start state.
  absl::StatusOr<ComponentChain> Finish(bool many_blocks) &&;

 private:
  struct Entry {
    uint32_t state;  // level-0 warm-up copy of the entry state (or the hub)
    uint32_t map;    // map used on the step into the warm-up
  };

  uint32_t AddState(Kind kind, uint32_t row, uint32_t col, uint32_t level) {
    out_.states.push_back({kind, row, col, level});
    out_.chain.states.emplace_back();
    out_.chain.states.back().plotted = false;
    out_.chain.states.back().label = -1;
    return static_cast<uint32_t>(out_.chain.states.size() - 1);
  }
  absl::Status Reserve(size_t more) const {
    if (out_.chain.states.size() + more > options_.max_states)
      return absl::ResourceExhaustedError(absl::StrCat("the chain for IFS matrix ", Quoted(name_),
                                                       " needs more than ", options_.max_states,
                                                       " states"));
    return absl::OkStatus();
  }
  void AddTransition(uint32_t state, uint32_t map, uint32_t next) {
    out_.chain.states[state].transitions.push_back({map, next});
    out_.chain.states[state].probabilities.push_back(weight_[map]);
  }

  std::vector<char> LiveRows(uint32_t j, const std::vector<Component>& selection) const;
  std::vector<char> SinkClasses(const std::vector<char>& live) const;
  absl::Status AddWarmup(uint32_t j, uint32_t s, const std::vector<char>& live,
                         const std::vector<uint32_t>& index);
  Entry RestartTarget();

  const std::vector<PointMap>& maps_;
  const IfsMatrix& m_;
  const BoolMatrix r_;
  const BoolMatrix& limit_;
  const std::vector<uint32_t> scc_;
  std::string_view name_;
  const ComponentChainOptions& options_;
  const std::vector<double> weight_;

  ComponentChain out_;
  std::vector<Entry> entries_;
  // Live states that may restart: (chain state, must restart).
  std::vector<std::pair<uint32_t, bool>> restarting_;
  uint32_t longest_warmup_ = 1;
};

// Rows with a non-empty component in column j that a selected row of this
// column reaches through such rows.
std::vector<char> ChainBuilder::LiveRows(uint32_t j,
                                         const std::vector<Component>& selection) const {
  const uint32_t n = m_.size();
  std::vector<char> live(n, 0);
  std::vector<uint32_t> queue;
  for (const Component& c : selection)
    if (c.col == j && !live[c.row]) live[c.row] = 1, queue.push_back(c.row);
  for (size_t q = 0; q < queue.size(); ++q)
    for (uint32_t s = 0; s < n; ++s)
      if (r_.Get(queue[q], s) && limit_.Get(s, j) && !live[s]) live[s] = 1, queue.push_back(s);
  return live;
}

// By class id: 1 for classes with no edge to another live class.
std::vector<char> ChainBuilder::SinkClasses(const std::vector<char>& live) const {
  const uint32_t n = m_.size();
  std::vector<char> is_sink(n, 1);
  for (uint32_t s = 0; s < n; ++s)
    if (live[s])
      for (uint32_t t = 0; t < n; ++t)
        if (live[t] && r_.Get(s, t) && scc_[t] != scc_[s]) is_sink[scc_[s]] = 0;
  return is_sink;
}

absl::Status ChainBuilder::AddBlock(uint32_t j, const std::vector<Component>& selection,
                                    const std::map<std::pair<uint32_t, uint32_t>, int32_t>& label) {
  const uint32_t n = m_.size();
  const std::vector<char> live = LiveRows(j, selection);
  NIMBUS_RETURN_IF_ERROR(Reserve(size_t(std::count(live.begin(), live.end(), 1))));
  std::vector<uint32_t> index(n, 0);
  for (uint32_t s = 0; s < n; ++s) {
    if (!live[s]) continue;
    index[s] = AddState(Kind::kLive, s, j, 0);
    if (auto it = label.find({s, j}); it != label.end()) {
      out_.chain.states[index[s]].plotted = true;
      out_.chain.states[index[s]].label = it->second;
    }
  }
  // Predecessor edges inside the block.
  for (uint32_t s = 0; s < n; ++s) {
    if (!live[s]) continue;
    for (uint32_t p = 0; p < n; ++p)
      if (live[p])
        for (uint32_t f : m_.at(p, s)) AddTransition(index[s], f, index[p]);
  }
  const std::vector<char> is_sink = SinkClasses(live);
  std::vector<char> class_done(n, 0);
  for (uint32_t s = 0; s < n; ++s) {
    if (!live[s] || !is_sink[scc_[s]] || class_done[scc_[s]]) continue;
    class_done[scc_[s]] = 1;
    NIMBUS_RETURN_IF_ERROR(AddWarmup(j, s, live, index));
  }
  // Which live states restart: outside sink classes, or stuck.
  for (uint32_t s = 0; s < n; ++s)
    if (live[s])
      restarting_.push_back(
          {index[s], !is_sink[scc_[s]] || out_.chain.states[index[s]].transitions.empty()});
  return absl::OkStatus();
}

// Unplotted level copies of the sink class of state s, walking only its
// internal edges; the last level feeds the live states in `index`.
absl::Status ChainBuilder::AddWarmup(uint32_t j, uint32_t s, const std::vector<char>& live,
                                     const std::vector<uint32_t>& index) {
  const uint32_t n = m_.size();
  const uint32_t cls = scc_[s];
  std::vector<uint32_t> members;
  for (uint32_t t = 0; t < n; ++t)
    if (live[t] && scc_[t] == cls) members.push_back(t);
  // Warm-up length from the class's internal maps.
  bool has_internal = false, unknown = false;
  uint32_t entry_map = 0;
  double c_max = 0;
  for (uint32_t a : members)
    for (uint32_t b : members)
      for (uint32_t f : m_.at(a, b)) {
        if (!has_internal) entry_map = f;  // any bounded map will do
        has_internal = true;
        if (!HasNoVariations(maps_[f])) unknown = true;
        c_max = std::max(c_max, AffineOf(maps_[f]).ContractionFactor());
      }
  if (!has_internal)
    return absl::InternalError(
        absl::StrCat("IFS matrix ", Quoted(name_), ": sink class of state ", s, " has no cycle"));
  uint32_t steps = options_.warmup_steps;
  if (steps == 0) steps = DerivedWarmupSteps(options_, c_max, unknown);
  longest_warmup_ = std::max(longest_warmup_, steps);
  NIMBUS_RETURN_IF_ERROR(Reserve(size_t{steps} * members.size()));
  // Copies are laid out level by level: copy (l, a) is first + l*size + pos(a).
  std::vector<uint32_t> pos(n, 0);
  for (uint32_t k = 0; k < members.size(); ++k) pos[members[k]] = k;
  const uint32_t first = static_cast<uint32_t>(out_.chain.states.size());
  const uint32_t width = static_cast<uint32_t>(members.size());
  for (uint32_t l = 0; l < steps; ++l)
    for (uint32_t a : members) AddState(Kind::kWarmup, a, j, l);
  for (uint32_t l = 0; l < steps; ++l)
    for (uint32_t a : members)
      for (uint32_t p : members)
        for (uint32_t f : m_.at(p, a))
          AddTransition(first + l * width + pos[a], f,
                        l + 1 < steps ? first + (l + 1) * width + pos[p] : index[p]);
  entries_.push_back({first + pos[members[0]], entry_map});
  return absl::OkStatus();
}

// Where a restart goes: straight into the only warm-up, or to a hub that
// picks one uniformly (its state is reserved by the caller).
ChainBuilder::Entry ChainBuilder::RestartTarget() {
  if (entries_.size() == 1) return entries_[0];
  const uint32_t hub = AddState(Kind::kRestart, 0, 0, 0);
  for (const Entry& e : entries_) AddTransition(hub, e.map, e.state);
  out_.chain.states[hub].probabilities.assign(entries_.size(), 1.0);
  return {hub, entries_[0].map};
}

absl::StatusOr<ComponentChain> ChainBuilder::Finish(bool many_blocks) && {
  if (entries_.empty()) return absl::InternalError("no sink class to start the chain from");
  double rho = options_.restart_probability;
  if (!(rho > 0)) rho = 1.0 / (2.0 * longest_warmup_);
  rho = std::clamp(rho, 1e-9, 1.0);
  if (entries_.size() > 1) NIMBUS_RETURN_IF_ERROR(Reserve(1));
  const Entry target = RestartTarget();
  for (auto [state, needs] : restarting_) {
    ChainState& st = out_.chain.states[state];
    if (!needs && !many_blocks) continue;
    const double p_restart = st.transitions.empty() ? 1.0 : rho;
    // Normalise the regular part to 1 - p_restart, then add the restart.
    double total = 0;
    for (double w : st.probabilities) total += w;
    for (double& w : st.probabilities) w = w / total * (1.0 - p_restart);
    st.transitions.push_back({target.map, target.state});
    st.probabilities.push_back(p_restart);
  }
  // Normalise every state (restarting ones are already, up to rounding).
  for (ChainState& st : out_.chain.states) {
    double total = 0;
    for (double w : st.probabilities) total += w;
    for (double& w : st.probabilities) w /= total;
  }
  // Several blocks start at the hub, so the first block is not favoured.
  out_.chain.start_state = target.state;
  return std::move(out_);
}

}  // namespace

absl::StatusOr<ComponentChain> BuildComponentChain(const std::vector<PointMap>& maps,
                                                   const IfsMatrix& m,
                                                   const std::vector<Component>& selection,
                                                   std::string_view name,
                                                   const ComponentChainOptions& options) {
  NIMBUS_RETURN_IF_ERROR(ValidateMatrix(m, maps.size(), name));
  NIMBUS_ASSIGN_OR_RETURN(const BoolMatrix limit, AperiodicLimitPattern(m, name));
  NIMBUS_RETURN_IF_ERROR(CheckSelection(limit, selection, name));
  NIMBUS_ASSIGN_OR_RETURN(std::vector<double> weight, MapWeights(maps, m, name, options));

  // Selected columns in order of first appearance; label of every selected
  // (row, col) is its first index in `selection`.
  std::vector<uint32_t> columns;
  std::map<std::pair<uint32_t, uint32_t>, int32_t> label;
  for (size_t k = 0; k < selection.size(); ++k) {
    const Component c = selection[k];
    if (std::find(columns.begin(), columns.end(), c.col) == columns.end()) columns.push_back(c.col);
    label.emplace(std::make_pair(c.row, c.col), static_cast<int32_t>(k));
  }
  ChainBuilder builder(maps, m, limit, name, options, std::move(weight));
  for (uint32_t j : columns) NIMBUS_RETURN_IF_ERROR(builder.AddBlock(j, selection, label));
  return std::move(builder).Finish(columns.size() > 1);
}

}  // namespace nimbus
