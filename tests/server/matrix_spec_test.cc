// chaos_game.matrices through the spec layer (ConvertSpec) and the runner
// (RunJobPlan): conversion, checks with field paths, the 1x1 = plain
// IFS identity, and the component grid.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <map>

#include "core/chaos/chaos_game.h"
#include "core/matrix/component_grid.h"
#include "core/io/vdb_io.h"
#include "core/matrix/ifs_matrix_plan.h"
#include "server/memory_admission.h"
#include "proto/spec_convert.h"
#include "proto/spec_io.h"
#include "server/job_runner.h"
#include "tests/support/fake_job_context.h"
#include "tests/support/test_util.h"

namespace nimbus::spec {
namespace {

using ::testing::AllOf;
using ::testing::HasSubstr;

v1::JobSpec Load(const std::string& example) {
  auto spec = LoadSpecFile(testing::SourcePath("examples/" + example));
  EXPECT_TRUE(spec.ok()) << spec.status();
  return spec.ok() ? *spec : v1::JobSpec();
}

v1::JobSpec Parse(const std::string& json) {
  auto spec = ParseSpec(json, SpecFormat::kJson);
  EXPECT_TRUE(spec.ok()) << spec.status();
  return spec.ok() ? *spec : v1::JobSpec();
}

// A small tree spec to mutate: two matrices and an expression.
constexpr char kTree[] = R"({
  "name": "t",
  "grid": {"resolution": [4, 64, 64], "bounds_min": {"x": -0.05, "y": -0.05, "z": -0.9},
           "bounds_max": {"x": 0.05, "y": 1.85, "z": 0.9}},
  "chaos_game": {
    "matrices": {
      "maps": [
        {"name": "T1", "steps": [{"scale": {"uniform": 0.5}}]},
        {"name": "T2", "steps": [{"translate": {"y": 0.5}}, {"scale": {"uniform": 0.5}}]},
        {"name": "T3", "steps": [{"translate": {"y": 1}}, {"rotate": {"axis": {"x": 1}, "degrees": 45}},
                                 {"scale": {"uniform": 0.5}}]},
        {"name": "T4", "steps": [{"translate": {"y": 1}}, {"rotate": {"axis": {"x": 1}, "degrees": -45}},
                                 {"scale": {"uniform": 0.5}}]}
      ],
      "matrices": [
        {"name": "H", "rows": [{"entries": [{"maps": ["T3", "T4"]}, {"maps": ["T1", "T2"]}]},
                               {"entries": [{}, {"maps": ["T1", "T2"]}]}]},
        {"name": "swap", "rows": [{"entries": [{}, {"maps": ["T1"]}]},
                                  {"entries": [{"maps": ["T2"]}, {}]}]}
      ],
      "expressions": [{"name": "H2", "expression": {"composition_of": {"operands": [
        {"matrix": "H"}, {"matrix": "H"}]}}}],
      "render": {"matrix": "H"},
      "components": [{"row": 0, "col": 1}]
    },
    "iterations": "200000",
    "seed": "5"
  }
})";

absl::StatusOr<JobPlan> Convert(const v1::JobSpec& spec) { return ConvertSpec(spec, {}); }

std::string Message(const absl::StatusOr<JobPlan>& job) {
  return std::string(job.status().message());
}

TEST(MatrixSpec, TreeExampleConverts) {
  auto job = Convert(Load("tree_matrix.json"));
  ASSERT_TRUE(job.ok()) << job.status();
  ASSERT_NE(job->ifs_matrix(), nullptr);
  EXPECT_EQ(job->ifs_matrix()->matrix.size(), 2u);
  EXPECT_EQ(job->ifs_matrix()->selection, (std::vector<Component>{{0, 0}, {0, 1}, {1, 1}}));
  EXPECT_EQ(job->ifs_matrix()->component_grid, ComponentGridType::kInt);
  EXPECT_EQ(job->ifs_matrix()->component_runs.size(), 3u);
  ASSERT_TRUE(job->point_run()->chain.has_value());
  EXPECT_EQ(job->point_run()->ifs.maps.size(), 4u);
  EXPECT_EQ(job->point_run()->ifs.probabilities.size(), 4u);
  // The iterations are split over the component runs without loss.
  uint64_t total = 0;
  for (const auto& run : job->ifs_matrix()->component_runs) total += run.iterations;
  EXPECT_EQ(total, job->point_run()->iterations);
  // The engine accepts the whole-object run and every component run.
  EXPECT_TRUE(ChaosGame::Create(*job->point_run(), 1).ok());
  for (const auto& run : job->ifs_matrix()->component_runs)
    EXPECT_TRUE(ChaosGame::Create(run, 1).ok());
}

TEST(MatrixSpec, ConstructiveExampleReportsEverySize) {
  auto job = Convert(Load("constructive.json"));
  ASSERT_TRUE(job.ok()) << job.status();
  const IfsMatrixPlan& plan = *job->ifs_matrix();
  // Named steps and then the render expression, at depth 0 each.
  ASSERT_EQ(plan.expansion.size(), 4u);
  EXPECT_EQ(plan.expansion[0].expression, "tet_then_dual");
  EXPECT_EQ(plan.expansion[0].size, 2u);
  EXPECT_EQ(plan.expansion[1].expression, "shuffled");
  EXPECT_EQ(plan.expansion[1].size, 2u);
  EXPECT_EQ(plan.expansion[2].expression, "bridged");
  EXPECT_EQ(plan.expansion[3].size, 2u);
  // tet_then_dual = [[tet, {id}], [{}, dual]] (4 + 1 + 4). The shuffle with
  // rod = {c000, c111} adds one new map to each diagonal entry (tet has c000
  // already, dual c111); the bridge adds c011 to (0, 1).
  EXPECT_EQ(plan.expansion[0].map_references, 9u);
  EXPECT_EQ(plan.expansion[1].map_references, 11u);
  EXPECT_EQ(plan.expansion[2].map_references, 12u);
  // initial {0, 1} x final {1}.
  EXPECT_EQ(plan.selection, (std::vector<Component>{{0, 1}, {1, 1}}));
  bool reported = false;
  for (const auto& w : job->warnings)
    reported |= w.find("shuffled: 2x2, 11 map references") != std::string::npos;
  EXPECT_TRUE(reported) << ::testing::PrintToString(job->warnings);
}

TEST(MatrixSpec, MutableTreeConverts) {
  auto job = Convert(Parse(kTree));
  ASSERT_TRUE(job.ok()) << job.status();
  EXPECT_EQ(job->ifs_matrix()->component_grid, ComponentGridType::kNone);
  EXPECT_TRUE(job->ifs_matrix()->component_runs.empty());
  EXPECT_GT(job->ifs_matrix()->chain_states, 2u);
  EXPECT_EQ(job->work.total, 200000u);
  // The chain of component (0, 1) of H: from the start, 17 unplotted
  // steps of A_11's maps {T1, T2} forget the start point; a state for
  // A_11 = {T1, T2} A_11 feeds the plotted state of A_01 = {T3, T4} A_01 U
  // {T1, T2} A_11, which restarts with probability 1/34.
  const MarkovChain& chain = *job->point_run()->chain;
  const auto& maps = job->point_run()->ifs.maps;
  auto name = [&](const ChainTransition& t) { return maps[t.map].name; };
  ASSERT_EQ(chain.states.size(), 19u);
  uint32_t s = chain.start_state;
  for (int step = 0; step < 17; ++step) {
    const ChainState& st = chain.states[s];
    ASSERT_FALSE(st.plotted) << "warm-up state " << step;
    ASSERT_EQ(st.transitions.size(), 2u);
    EXPECT_EQ(name(st.transitions[0]), "T1");
    EXPECT_EQ(name(st.transitions[1]), "T2");
    EXPECT_EQ(st.transitions[0].next_state, st.transitions[1].next_state);
    EXPECT_DOUBLE_EQ(st.probabilities[0], 0.5);
    s = st.transitions[0].next_state;
  }
  const ChainState& a11 = chain.states[s];
  EXPECT_FALSE(a11.plotted);
  ASSERT_EQ(a11.transitions.size(), 4u);
  uint32_t plotted = 0;
  for (size_t i = 0; i < chain.states.size(); ++i) plotted += chain.states[i].plotted;
  EXPECT_EQ(plotted, 1u);
  for (size_t t = 0; t < 4; ++t) {
    EXPECT_EQ(name(a11.transitions[t]), t % 2 ? "T2" : "T1");
    EXPECT_DOUBLE_EQ(a11.probabilities[t], 0.25);
    const uint32_t next = a11.transitions[t].next_state;
    EXPECT_TRUE(next == s || chain.states[next].plotted) << t;
  }
  const uint32_t p = a11.transitions[0].next_state == s ? a11.transitions[2].next_state
                                                         : a11.transitions[0].next_state;
  const ChainState& a01 = chain.states[p];
  ASSERT_TRUE(a01.plotted);
  EXPECT_EQ(a01.label, 0);
  ASSERT_EQ(a01.transitions.size(), 3u);
  EXPECT_EQ(name(a01.transitions[0]), "T3");
  EXPECT_EQ(name(a01.transitions[1]), "T4");
  EXPECT_EQ(a01.transitions[0].next_state, p);
  EXPECT_EQ(a01.transitions[1].next_state, p);
  EXPECT_EQ(a01.transitions[2].next_state, chain.start_state);
  EXPECT_NEAR(a01.probabilities[2], 1.0 / 34, 1e-12);
  EXPECT_NEAR(a01.probabilities[0], 33.0 / 68, 1e-12);
  auto memory = server::AdmitMemory(*job, {}, 2);
  ASSERT_TRUE(memory.ok()) << memory.status();
  EXPECT_GT(memory->estimated_bytes, 0u);
}

TEST(MatrixSpec, UnknownMapIsNamedWithItsPath) {
  v1::JobSpec spec = Parse(kTree);
  spec.mutable_chaos_game()
      ->mutable_matrices()
      ->mutable_matrices(0)
      ->mutable_rows(1)
      ->mutable_entries(1)
      ->set_maps(0, "T9");
  auto job = Convert(spec);
  ASSERT_EQ(job.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(Message(job),
              AllOf(HasSubstr("chaos_game.matrices.matrices[0].rows[1].entries[1].maps[0]"),
                    HasSubstr("'T9'"), HasSubstr("T1")));
}

TEST(MatrixSpec, UnknownMatrixIsNamedWithItsPath) {
  v1::JobSpec spec = Parse(kTree);
  spec.mutable_chaos_game()
      ->mutable_matrices()
      ->mutable_expressions(0)
      ->mutable_expression()
      ->mutable_composition_of()
      ->mutable_operands(1)
      ->set_matrix("G");
  auto job = Convert(spec);
  ASSERT_EQ(job.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(Message(job),
              AllOf(HasSubstr("chaos_game.matrices.expressions[0].expression.composition_of."
                              "operands[1].matrix"),
                    HasSubstr("'G'"), HasSubstr("known: H, swap")));
  spec = Parse(kTree);
  spec.mutable_chaos_game()->mutable_matrices()->mutable_render()->set_matrix("nope");
  job = Convert(spec);
  EXPECT_THAT(Message(job), AllOf(HasSubstr("chaos_game.matrices.render.matrix"),
                                  HasSubstr("'nope'"), HasSubstr("H2")));
}

TEST(MatrixSpec, PeriodicMatrixIsRefused) {
  v1::JobSpec spec = Parse(kTree);
  spec.mutable_chaos_game()->mutable_matrices()->mutable_render()->set_matrix("swap");
  auto job = Convert(spec);
  ASSERT_EQ(job.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(Message(job), AllOf(HasSubstr("chaos_game.matrices.render"), HasSubstr("swap"),
                                  HasSubstr("period")));
}

TEST(MatrixSpec, EmptyOrBadComponentsAreRefused) {
  v1::JobSpec spec = Parse(kTree);
  auto* comp = spec.mutable_chaos_game()->mutable_matrices()->mutable_components(0);
  comp->set_row(1);
  comp->set_col(0);
  auto job = Convert(spec);
  ASSERT_EQ(job.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(Message(job), AllOf(HasSubstr("chaos_game.matrices.components[0]"),
                                  HasSubstr("(1, 0)"), HasSubstr("empty")));
  comp->set_row(2);
  EXPECT_THAT(Message(Convert(spec)), HasSubstr("outside the 2x2 matrix"));

  // Automaton-style selection with only empty components.
  spec = Parse(kTree);
  auto* ms = spec.mutable_chaos_game()->mutable_matrices();
  ms->clear_components();
  ms->add_initial_states(1);
  ms->add_final_states(0);
  EXPECT_THAT(Message(Convert(spec)),
              AllOf(HasSubstr("chaos_game.matrices.final_states"), HasSubstr("empty")));
  // Both ways at once.
  ms->add_components()->set_col(1);
  EXPECT_THAT(Message(Convert(spec)), HasSubstr("exactly one way"));
}

TEST(MatrixSpec, StateSelectionPicksNonEmptyComponents) {
  v1::JobSpec spec = Parse(kTree);
  auto* ms = spec.mutable_chaos_game()->mutable_matrices();
  ms->clear_components();
  ms->add_initial_states(0);
  ms->add_initial_states(1);
  ms->add_final_states(0);
  ms->add_final_states(1);
  auto job = Convert(spec);
  ASSERT_TRUE(job.ok()) << job.status();
  EXPECT_EQ(job->ifs_matrix()->selection, (std::vector<Component>{{0, 0}, {0, 1}, {1, 1}}));
}

TEST(MatrixSpec, MalformedMatricesAreRefused) {
  v1::JobSpec spec = Parse(kTree);
  auto* ms = spec.mutable_chaos_game()->mutable_matrices();
  ms->mutable_matrices(0)->mutable_rows(1)->add_entries();
  EXPECT_THAT(Message(Convert(spec)),
              AllOf(HasSubstr("chaos_game.matrices.matrices[0].rows[1].entries"),
                    HasSubstr("needs 2 entries; got 3")));
  spec = Parse(kTree);
  spec.mutable_chaos_game()->mutable_matrices()->mutable_maps(3)->set_name("T1");
  EXPECT_THAT(Message(Convert(spec)), AllOf(HasSubstr("chaos_game.matrices.maps[3].name"),
                                            HasSubstr("duplicate map name 'T1'")));
  spec = Parse(kTree);
  spec.mutable_chaos_game()->mutable_matrices()->mutable_expressions(0)->set_name("H");
  EXPECT_THAT(Message(Convert(spec)), HasSubstr("chaos_game.matrices.expressions[0].name"));
  spec = Parse(kTree);
  spec.mutable_chaos_game()
      ->mutable_matrices()
      ->mutable_expressions(0)
      ->mutable_expression()
      ->mutable_composition_of()
      ->mutable_operands()
      ->RemoveLast();
  EXPECT_THAT(Message(Convert(spec)), HasSubstr("needs at least 2 operands"));
  // Size mismatch is reported by the core, behind the field path.
  spec = Parse(kTree);
  auto* ops = spec.mutable_chaos_game()->mutable_matrices()->mutable_render()->mutable_union_of();
  ops->add_operands()->set_matrix("H");
  auto* t = ops->add_operands()->mutable_tensor_product_of();
  t->add_operands()->set_matrix("H");
  t->add_operands()->set_matrix("H");
  auto job = Convert(spec);
  EXPECT_EQ(job.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(Message(job), HasSubstr("chaos_game.matrices.render"));
}

TEST(MatrixSpec, ExpansionBeyondTheLimitIsResourceExhausted) {
  v1::JobSpec spec = Parse(kTree);
  // H (x) H (x) ... ten times: 2^10 = 1024 states > 512.
  auto* ops =
      spec.mutable_chaos_game()->mutable_matrices()->mutable_render()->mutable_tensor_product_of();
  for (int i = 0; i < 10; ++i) ops->add_operands()->set_matrix("H");
  auto job = Convert(spec);
  ASSERT_EQ(job.status().code(), absl::StatusCode::kResourceExhausted) << job.status();
  EXPECT_THAT(Message(job), HasSubstr("chaos_game.matrices.render"));
}

TEST(MatrixSpec, ExpansionSizesAreReported) {
  auto job = Convert(Parse(kTree));
  ASSERT_TRUE(job.ok()) << job.status();
  ASSERT_EQ(job->ifs_matrix()->expansion.size(), 2u);
  // H o H: (0,0) = {T3,T4}^2 (4), (0,1) = 4 + 4, (1,1) = 4.
  EXPECT_EQ(job->ifs_matrix()->expansion[0].expression, "H2");
  EXPECT_EQ(job->ifs_matrix()->expansion[0].map_references, 16u);
  bool reported = false;
  for (const auto& w : job->warnings)
    reported |= w.find("H2: 2x2, 16 map references") != std::string::npos;
  EXPECT_TRUE(reported) << ::testing::PrintToString(job->warnings);
}

// --- A 1x1 matrix renders exactly like the plain IFS -----------------------

constexpr char kPlain[] = R"({
  "grid": {"resolution": [48], "bounds_min": {"x": -1, "y": -1, "z": -1},
           "bounds_max": {"x": 1, "y": 1, "z": 1}},
  "chaos_game": {
    "ifs": {"maps": [
      {"name": "a", "steps": [{"translate": {"x": 0.5, "y": 0.5, "z": 0.5}}, {"scale": {"uniform": 0.5}}]},
      {"name": "b", "steps": [{"translate": {"x": 0.5, "y": -0.5, "z": -0.5}}, {"scale": {"uniform": 0.5}}]},
      {"name": "c", "steps": [{"translate": {"x": -0.5, "y": 0.5, "z": -0.5}},
                              {"rotate": {"axis": {"z": 1}, "degrees": 30}}, {"scale": {"uniform": 0.45}}]},
      {"name": "d", "steps": [{"translate": {"x": -0.5, "y": -0.5, "z": 0.5}}, {"scale": {"xyz": {"x": 0.5, "y": 0.4, "z": 0.6}}}]}
    ]},
    "iterations": "3000000",
    "seed": "11"
  }
})";

// The same maps as a 1x1 matrix; `render` varies per test.
v1::JobSpec AsMatrix(const std::string& render_json, const std::string& matrices_json) {
  v1::JobSpec plain = Parse(kPlain);
  v1::JobSpec spec = plain;
  auto* ms = spec.mutable_chaos_game()->mutable_matrices();
  *ms->mutable_maps() = plain.chaos_game().ifs().maps();
  spec.mutable_chaos_game()->clear_ifs();
  v1::JobSpec extra =
      Parse(R"({"chaos_game": {"matrices": {"matrices": )" + matrices_json + R"(, "render": )" +
            render_json + R"(, "components": [{"row": 0, "col": 0}]}}})");
  *ms->mutable_matrices() = extra.chaos_game().matrices().matrices();
  *ms->mutable_render() = extra.chaos_game().matrices().render();
  *ms->mutable_components() = extra.chaos_game().matrices().components();
  return spec;
}

CountGrid Render(const v1::JobSpec& spec, int threads) {
  auto job = ConvertSpec(spec, {});
  EXPECT_TRUE(job.ok()) << job.status();
  auto game = ChaosGame::Create(*job->point_run(), threads);
  EXPECT_TRUE(game.ok()) << game.status();
  EXPECT_TRUE((*game)->Run(nullptr).ok());
  return (*game)->TakeCounts();
}

void ExpectSameCounts(const CountGrid& a, const CountGrid& b) {
  ASSERT_EQ(a.resolution(), b.resolution());
  EXPECT_EQ(a.Total(), b.Total());
  const Int3 r = a.resolution();
  int64_t differing = 0;
  for (int x = 0; x < r.x; ++x)
    for (int y = 0; y < r.y; ++y)
      for (int z = 0; z < r.z; ++z) differing += a.Get(x, y, z) != b.Get(x, y, z);
  EXPECT_EQ(differing, 0);
}

TEST(MatrixSpec, OneByOneMatrixIsBitwiseThePlainIfs) {
  const v1::JobSpec plain = Parse(kPlain);
  const v1::JobSpec matrix =
      AsMatrix(R"({"matrix": "M"})",
               R"([{"name": "M", "rows": [{"entries": [{"maps": ["a", "b", "c", "d"]}]}]}])");
  for (int threads : {1, 2}) {
    const CountGrid expected = Render(plain, threads);
    EXPECT_GT(expected.Total(), 0u);
    ExpectSameCounts(Render(matrix, threads), expected);
  }
  // The converted jobs agree field by field where the engine looks.
  auto pj = ConvertSpec(plain, {}), mj = ConvertSpec(matrix, {});
  ASSERT_TRUE(pj.ok() && mj.ok());
  EXPECT_FALSE(mj->point_run()->chain.has_value());
  EXPECT_EQ(mj->point_run()->ifs.probabilities, pj->point_run()->ifs.probabilities);
  EXPECT_EQ(mj->point_run()->warmup, pj->point_run()->warmup);
}

TEST(MatrixSpec, OneByOneUnionIsBitwiseThePlainIfs) {
  // Built from two halves: the union's entry lists the maps in table order.
  const v1::JobSpec matrix =
      AsMatrix(R"({"union_of": {"operands": [{"matrix": "cd"}, {"matrix": "ab"}]}})",
               R"([{"name": "ab", "rows": [{"entries": [{"maps": ["b", "a"]}]}]},
          {"name": "cd", "rows": [{"entries": [{"maps": ["d", "c"]}]}]}])");
  ExpectSameCounts(Render(matrix, 2), Render(Parse(kPlain), 2));
}

// --- The runner and the component grid --------------------------------------


TEST(MatrixRunner, TreeComponentGridLabelsTheComponents) {
  testing::TempDir dir;
  v1::JobSpec spec = Load("tree_matrix.json");
  spec.mutable_grid()->set_resolution(0, 5);
  spec.mutable_grid()->set_resolution(1, 128);
  spec.mutable_grid()->set_resolution(2, 120);
  spec.mutable_chaos_game()->set_iterations(3000000);
  auto job = ConvertSpec(spec, {});
  ASSERT_TRUE(job.ok()) << job.status();
  testing::FakeJobContext ctx(dir / "tree.vdb");
  ASSERT_TRUE(server::RunJobPlan(*job, ctx).ok());
  EXPECT_EQ(ctx.stats["matrix_size"], 2u);
  EXPECT_EQ(ctx.stats["matrix_components"], 3u);
  // Every component's points, counted once, in one iterating phase.
  EXPECT_TRUE(ctx.progress_ordered);
  const auto iterating = ctx.Last(server::JobPhase::kIterating);
  EXPECT_EQ(iterating.done, 3000000u);
  EXPECT_EQ(iterating.total, 3000000u);
  EXPECT_EQ(iterating.unit, "points");
  EXPECT_EQ(ctx.Last(server::JobPhase::kWriting).done, 1u);

  auto density = ReadVdbFile(dir / "tree.vdb", "density");
  ASSERT_TRUE(density.ok()) << density.status();
  const Int3 r = density->frame.resolution;
  auto labels = ReadComponentGrid(dir / "tree.vdb", r);
  ASSERT_TRUE(labels.ok()) << labels.status();
  const Vec3 h = density->frame.VoxelSize();
  std::vector<int64_t> per_label(3, 0);
  for (int x = 0; x < r.x; ++x)
    for (int y = 0; y < r.y; ++y)
      for (int z = 0; z < r.z; ++z) {
        const int32_t label = (*labels)[(size_t(x) * r.y + y) * r.z + z];
        // Labels exactly where there is density.
        ASSERT_EQ(label >= 0, density->At(x, y, z) > 0) << x << " " << y << " " << z;
        if (label < 0) continue;
        ASSERT_LT(label, 3);
        ++per_label[size_t(label)];
        if (label == 2) {
          // A_22 (selection index 2) is the trunk: x = z = 0, y in [0, 1].
          const Vec3 p =
              density->frame.bounds.min + Vec3{(x + 0.5) * h.x, (y + 0.5) * h.y, (z + 0.5) * h.z};
          EXPECT_LE(std::abs(p.z), h.z);
          EXPECT_GE(p.y, -h.y);
          EXPECT_LE(p.y, 1 + h.y);
        }
      }
  // Every component owns some voxels: canopy, branches and trunk.
  for (int64_t n : per_label) EXPECT_GT(n, 0);
  EXPECT_EQ(ctx.stats["component_0_voxels"], uint64_t(per_label[0]));
}

TEST(MatrixRunner, ConstructiveFloatComponentGrid) {
  testing::TempDir dir;
  v1::JobSpec spec = Load("constructive.json");
  spec.mutable_grid()->set_resolution(0, 32);
  spec.mutable_chaos_game()->set_iterations(400000);
  spec.mutable_chaos_game()->mutable_matrices()->set_component_grid(v1::COMPONENT_GRID_FLOAT);
  auto job = ConvertSpec(spec, {});
  ASSERT_TRUE(job.ok()) << job.status();
  testing::FakeJobContext ctx(dir / "c.vdb");
  ASSERT_TRUE(server::RunJobPlan(*job, ctx).ok());
  // A float grid, so the generic float reader sees it too.
  auto as_float = ReadVdbFile(dir / "c.vdb", "component");
  ASSERT_TRUE(as_float.ok()) << as_float.status();
  auto density = ReadVdbFile(dir / "c.vdb", "density");
  ASSERT_TRUE(density.ok()) << density.status();
  auto labels = ReadComponentGrid(dir / "c.vdb", density->frame.resolution);
  ASSERT_TRUE(labels.ok()) << labels.status();
  std::vector<int64_t> per_label(2, 0);
  for (size_t v = 0; v < labels->size(); ++v) {
    const int32_t label = (*labels)[v];
    ASSERT_EQ(label >= 0, density->values[v] > 0);
    ASSERT_LT(label, 2);
    if (label >= 0) ++per_label[size_t(label)];
  }
  EXPECT_GT(per_label[0], 0);
  EXPECT_GT(per_label[1], 0);
}

TEST(MatrixRunner, WithoutComponentGridRunsAsOneChaosGame) {
  testing::TempDir dir;
  v1::JobSpec spec = Parse(kTree);
  auto job = ConvertSpec(spec, {});
  ASSERT_TRUE(job.ok()) << job.status();
  testing::FakeJobContext ctx(dir / "t.vdb");
  ASSERT_TRUE(server::RunJobPlan(*job, ctx).ok());
  auto density = ReadVdbFile(dir / "t.vdb", "density");
  ASSERT_TRUE(density.ok()) << density.status();
  EXPECT_FALSE(ReadComponentGrid(dir / "t.vdb", density->frame.resolution).ok());
  EXPECT_GT(ctx.stats["matrix_chain_states"], 2u);
}

TEST(MatrixRunner, EngineOptionsApplyToMatrixJobs) {
  // Colour, raw counts and splatting are the engine's, so a matrix job
  // honours them as a plain IFS does.
  testing::TempDir dir;
  v1::JobSpec spec = Parse(kTree);
  spec.mutable_chaos_game()->mutable_color()->set_mode(v1::COLOR_MODE_ADDRESS);
  spec.mutable_chaos_game()->set_raw_counts(v1::RAW_COUNTS_FLOAT);
  auto job = ConvertSpec(spec, {});
  ASSERT_TRUE(job.ok()) << job.status();
  EXPECT_EQ(job->point_run()->color.mode, ColorMode::kAddress);
  EXPECT_EQ(job->density.raw_counts, RawCounts::kFloat);
  testing::FakeJobContext ctx(dir / "t.vdb");
  ASSERT_TRUE(server::RunJobPlan(*job, ctx).ok());
  auto cd = ReadVec3VdbFile(dir / "t.vdb");
  ASSERT_TRUE(cd.ok()) << cd.status();
  EXPECT_TRUE(std::any_of(cd->active.begin(), cd->active.end(), [](auto a) { return a != 0; }));
  EXPECT_TRUE(ReadVdbFile(dir / "t.vdb", "counts").ok());
}

TEST(MatrixSpec, OptionsAComponentGridCannotHonourAreRefusedByName) {
  v1::JobSpec spec = Parse(kTree);
  spec.mutable_chaos_game()->mutable_matrices()->set_component_grid(v1::COMPONENT_GRID_INT);
  ASSERT_TRUE(Convert(spec).ok());
  v1::JobSpec colour = spec;
  colour.mutable_chaos_game()->mutable_color()->set_mode(v1::COLOR_MODE_MAP);
  EXPECT_THAT(Message(Convert(colour)), HasSubstr("chaos_game.color: not supported"));
  v1::JobSpec conv = spec;
  conv.mutable_chaos_game()->mutable_convergence()->set_tolerance(0.01);
  EXPECT_THAT(Message(Convert(conv)), HasSubstr("chaos_game.convergence"));
  v1::JobSpec splat = spec;
  splat.mutable_chaos_game()->set_splat(true);
  EXPECT_THAT(Message(Convert(splat)), HasSubstr("chaos_game.splat"));
}

}  // namespace
}  // namespace nimbus::spec
