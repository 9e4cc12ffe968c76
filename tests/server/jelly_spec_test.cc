// Conversion of jelly specs (errors by field name, the stability rule, the
// examples) and the runner through a FakeJobContext: frames, progress in
// frames, the velocity grid, bitwise-identical frames for any thread
// count, and pokes that change the frames from theirs on and no earlier.
#include <gtest/gtest.h>

#include <tbb/task_arena.h>

#include "core/base/sha256.h"
#include "core/io/metadata_keys.h"
#include "core/io/vdb_io.h"
#include "proto/spec_convert.h"
#include "proto/spec_io.h"
#include "server/job_driver.h"
#include "server/job_runner.h"
#include "server/memory_admission.h"
#include "server/result_store.h"
#include "tests/support/fake_job_context.h"
#include "tests/support/test_util.h"

namespace nimbus::spec {
namespace {

v1::JobSpec Example(const std::string& name) {
  auto spec = LoadSpecFile(nimbus::testing::SourcePath("examples/" + name));
  EXPECT_TRUE(spec.ok()) << spec.status();
  return *spec;
}

// The Sierpinski example, small and short.
v1::JobSpec SmallSierpinski(uint32_t frames = 6) {
  v1::JobSpec spec = Example("jelly_sierpinski.json");
  spec.mutable_grid()->set_resolution(0, 32);
  spec.mutable_jelly()->set_frames(frames);
  spec.mutable_jelly()->set_depth(5);
  return spec;
}

std::string Error(const v1::JobSpec& spec) {
  auto job = ConvertSpec(spec, {});
  return job.ok() ? "ok" : std::string(job.status().message());
}

TEST(JellySpec, ExamplesConvertAndAreAdmitted) {
  for (const char* name : {"jelly_sierpinski.json", "jelly_tree.json"}) {
    auto job = ConvertSpec(Example(name), {});
    ASSERT_TRUE(job.ok()) << name << ": " << job.status();
    ASSERT_NE(job->jelly(), nullptr);
    EXPECT_EQ(job->work.unit, "frames");
    EXPECT_EQ(job->work.total, job->jelly()->frames);
    EXPECT_EQ(KindName(job->kind), "jelly");
    EXPECT_TRUE(server::AdmitMemory(*job, {}, 2).ok()) << name;
    // Pokes change a jelly result and are not in the spec.
    EXPECT_FALSE(job->result_cacheable()) << name;
  }
  EXPECT_TRUE(ConvertSpec(Example("tree.json"), {})->result_cacheable());
  auto job = ConvertSpec(Example("jelly_sierpinski.json"), {});
  EXPECT_EQ(job->jelly()->sim.bodies.size(), 4u);
  EXPECT_EQ(job->jelly()->sim.springs.size(), 6u);
  // Rest lengths default to the initial distances.
  const JellySim& sim = job->jelly()->sim;
  EXPECT_DOUBLE_EQ(sim.springs[0].rest_length,
                   Length(sim.bodies[1].position - sim.bodies[0].position));
  EXPECT_DOUBLE_EQ(sim.dt, 1.0 / 240);
}

TEST(JellySpec, TooLargeStepIsRefusedBySubstepsWithTheLimit) {
  v1::JobSpec spec = SmallSierpinski();
  spec.mutable_jelly()->set_substeps(1);
  spec.mutable_jelly()->mutable_springs(0)->set_stiffness(5000);
  const std::string e = Error(spec);
  EXPECT_EQ(e.rfind("jelly.substeps: ", 0), 0u) << e;
  EXPECT_NE(e.find("stability limit"), std::string::npos) << e;
  EXPECT_NE(e.find("2·sqrt(m/k)"), std::string::npos) << e;
  EXPECT_NE(e.find("use at least"), std::string::npos) << e;
}

TEST(JellySpec, BadFieldsAreNamed) {
  struct Case {
    std::function<void(v1::Jelly&)> edit;
    std::string prefix;
  };
  const std::vector<Case> cases = {
      {[](v1::Jelly& j) { j.mutable_bodies(1)->set_mass(-2); }, "jelly.bodies[1].mass: must be > 0"},
      {[](v1::Jelly& j) { j.mutable_bodies(2)->set_mass(0); }, "jelly.bodies[2].mass: must be > 0"},
      {[](v1::Jelly& j) { j.mutable_springs(3)->set_body_b(9); },
       "jelly.springs[3].body_b: no body 9"},
      {[](v1::Jelly& j) { j.mutable_springs(0)->set_body_a(-1); },
       "jelly.springs[0].body_a: no body -1"},
      {[](v1::Jelly& j) { j.mutable_springs(0)->set_body_b(0); },
       "jelly.springs[0].body_b: must differ"},
      {[](v1::Jelly& j) { j.mutable_springs(1)->set_stiffness(-1); },
       "jelly.springs[1].stiffness: must be >= 0"},
      {[](v1::Jelly& j) { j.mutable_bodies(0)->set_radius(-1); }, "jelly.bodies[0].radius"},
      {[](v1::Jelly& j) { j.clear_bodies(); }, "jelly.bodies: required"},
      {[](v1::Jelly& j) { j.set_frames(0); }, "jelly.frames"},
      {[](v1::Jelly& j) { j.set_depth(20); }, "jelly.depth"},
      {[](v1::Jelly& j) { j.set_render(v1::JELLY_RENDER_MODE_CHAOS_GAME); }, "jelly.points"},
      {[](v1::Jelly& j) { j.mutable_ground()->set_restitution(2); }, "jelly.ground.restitution"},
      {[](v1::Jelly& j) { j.mutable_wind()->set_drag(-1); }, "jelly.wind.drag"},
      {[](v1::Jelly& j) {
         auto* i = j.add_impulses();
         i->set_frame(3);
         i->mutable_push()->set_body(4);
         i->mutable_push()->mutable_impulse()->set_x(1);
       },
       "jelly.impulses[0].push.body: no body 4"},
      {[](v1::Jelly& j) { j.add_impulses()->set_frame(2); },
       "jelly.impulses[0].push: set impulse or drag_target"},
      {[](v1::Jelly& j) {
         auto* i = j.add_impulses();
         i->set_frame(6);
         i->mutable_push()->mutable_impulse()->set_x(1);
       },
       "jelly.impulses[0].frame: must be in [1, 6)"},
      {[](v1::Jelly& j) { j.mutable_springs(0)->clear_other(); }, "jelly.springs[0]: set body_b"},
      {[](v1::Jelly& j) { j.mutable_bodies(0)->mutable_position()->set_x(1e300); },
       "jelly.bodies[0].position"},
  };
  for (size_t i = 0; i < cases.size(); ++i) {
    v1::JobSpec spec = SmallSierpinski();
    cases[i].edit(*spec.mutable_jelly());
    const std::string e = Error(spec);
    EXPECT_EQ(e.rfind(cases[i].prefix, 0), 0u) << "case " << i << ": " << e;
  }
}

// Pokes from a list, as the worker's context would hand them out.
class PokingContext : public nimbus::testing::FakeJobContext {
 public:
  absl::StatusOr<std::vector<JellyPoke>> TakePokes(uint64_t frame) override {
    asked.push_back(frame);
    std::vector<JellyPoke> out;
    for (const JellyPoke& p : pokes)
      if (p.frame == frame) out.push_back(p);
    return out;
  }
  std::vector<JellyPoke> pokes;
  std::vector<uint64_t> asked;
};

// sha256 of every frame file of a run.
std::vector<std::string> RunAndHash(const v1::JobSpec& spec, int threads,
                                    std::vector<JellyPoke> pokes = {}) {
  auto job = ConvertSpec(spec, {});
  EXPECT_TRUE(job.ok()) << job.status();
  PokingContext ctx;
  ctx.pokes = std::move(pokes);
  tbb::task_arena arena(threads);
  absl::Status st;
  arena.execute([&] { st = server::RunJobPlan(*job, ctx); });
  EXPECT_TRUE(st.ok()) << st;
  EXPECT_TRUE(ctx.progress_ordered);
  const auto last = ctx.Last(server::JobPhase::kIterating);
  EXPECT_EQ(last.unit, "frames");
  EXPECT_EQ(last.done, job->jelly()->frames);
  std::vector<uint64_t> want_asked;
  for (uint64_t f = 1; f < job->jelly()->frames; ++f) want_asked.push_back(f);
  EXPECT_EQ(ctx.asked, want_asked);
  std::vector<std::string> hashes;
  const auto dir = server::ExtraFilesDir(ctx.result());
  for (uint64_t f = 0; f < job->jelly()->frames; ++f) {
    auto h = Sha256File(dir / server::FrameFileName(job->name, f));
    EXPECT_TRUE(h.ok()) << f;
    hashes.push_back(h.ok() ? *h : "");
  }
  // The result is the last frame (same grids, same metadata).
  EXPECT_EQ(*Sha256File(ctx.result()), hashes.back());
  return hashes;
}

TEST(JellyRunner, FramesWithVelocityAreBitwiseTheSameForAnyThreadCount) {
  const v1::JobSpec spec = SmallSierpinski();
  const auto one = RunAndHash(spec, 1);
  const auto four = RunAndHash(spec, 4);
  EXPECT_EQ(one, four);
  EXPECT_NE(one[0], one[5]);
}

TEST(JellyRunner, FramesCarryDensityVelocityAndMetadata) {
  auto job = ConvertSpec(SmallSierpinski(), {});
  ASSERT_TRUE(job.ok());
  nimbus::testing::FakeJobContext ctx;
  ASSERT_TRUE(server::RunJobPlan(*job, ctx).ok());
  const auto dir = server::ExtraFilesDir(ctx.result());
  auto frame = ReadVdbFile(dir / "jelly_sierpinski.0004.vdb");
  ASSERT_TRUE(frame.ok()) << frame.status();
  const MetaValue* index = frame->Find(meta_key::kJellyFrame);
  ASSERT_NE(index, nullptr);
  EXPECT_EQ(std::get<int64_t>(*index), 4);
  EXPECT_EQ(std::get<int64_t>(*frame->Find(meta_key::kJellyLeaves)), 1024);
  EXPECT_NEAR(std::get<double>(*frame->Find(meta_key::kJellyTime)), 3.0 / 24, 1e-12);
  auto v = ReadVec3VdbFile(dir / "jelly_sierpinski.0004.vdb", "v");
  ASSERT_TRUE(v.ok()) << v.status();
  // Same active voxels as the density; the jelly is falling.
  double vy = 0;
  size_t n = 0;
  for (size_t i = 0; i < v->values.size(); ++i) {
    EXPECT_EQ(v->active[i], frame->values[i] > 0) << i;
    if (v->active[i]) vy += v->values[i].y, ++n;
  }
  EXPECT_LT(vy / double(n), -0.5);
  EXPECT_EQ(ctx.stats["jelly_frames"], 6u);
  EXPECT_EQ(ctx.stats["jelly_steps"], 50u);
  EXPECT_EQ(ctx.stats["jelly_leaves"], 1024u);
}

TEST(JellyRunner, APokeChangesItsFrameOnwardAndNoEarlierFrame) {
  const v1::JobSpec spec = SmallSierpinski(8);
  const auto plain = RunAndHash(spec, 2);
  JellyPoke poke;
  poke.frame = 4;
  poke.body = 0;
  poke.vector = {3, 0, 0};
  const auto poked = RunAndHash(spec, 2, {poke});
  for (int f = 0; f < 4; ++f) EXPECT_EQ(plain[f], poked[f]) << f;
  for (int f = 4; f < 8; ++f) EXPECT_NE(plain[f], poked[f]) << f;
  // A drag also acts from its frame.
  poke.kind = JellyPoke::Kind::kDrag;
  poke.vector = {0, 2, 0};
  poke.stiffness = 100;
  poke.frames = 2;
  const auto dragged = RunAndHash(spec, 2, {poke});
  for (int f = 0; f < 4; ++f) EXPECT_EQ(plain[f], dragged[f]) << f;
  EXPECT_NE(plain[4], dragged[4]);
}

TEST(JellyRunner, SpecImpulsesActAtTheirFrame) {
  v1::JobSpec spec = SmallSierpinski(8);
  const auto plain = RunAndHash(spec, 2);
  auto* i = spec.mutable_jelly()->add_impulses();
  i->set_frame(5);
  i->mutable_push()->set_body(2);
  i->mutable_push()->mutable_impulse()->set_z(2);
  const auto kicked = RunAndHash(spec, 2);
  // The spec changed, so its hash in every frame's metadata did too; the
  // fake context writes no hash, so frames before 5 are the same bytes.
  for (int f = 0; f < 5; ++f) EXPECT_EQ(plain[f], kicked[f]) << f;
  for (int f = 5; f < 8; ++f) EXPECT_NE(plain[f], kicked[f]) << f;
}

}  // namespace
}  // namespace nimbus::spec
