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
#include "tests/support/jelly_oracles.h"
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

// One body and a grid of 1 cm voxels: VRR depth 1 from the origin puts the
// frame's single leaf at the body's position (its map applied to the
// origin is its translation), so the one lit voxel shows where it is.
v1::JobSpec OneBody(const std::string& body, const std::string& world, const std::string& grid,
                    int frames, int substeps) {
  auto spec = ParseSpec(R"({"name": "one", "grid": )" + grid + R"(,
    "jelly": {"bodies": [)" + body + "], " + world + R"(, "frames": )" +
                            std::to_string(frames) + R"(, "fps": 10, "substeps": )" +
                            std::to_string(substeps) + R"(, "depth": 1}})",
                        SpecFormat::kJson);
  EXPECT_TRUE(spec.ok()) << spec.status();
  return spec.ok() ? *spec : v1::JobSpec();
}

// Runs a OneBody spec; its frames stay in the context's folder.
std::unique_ptr<nimbus::testing::FakeJobContext> RunOneBody(const v1::JobSpec& spec) {
  auto ctx = std::make_unique<nimbus::testing::FakeJobContext>();
  auto job = ConvertSpec(spec, {});
  EXPECT_TRUE(job.ok()) << job.status();
  if (job.ok()) EXPECT_TRUE(server::RunJobPlan(*job, *ctx).ok());
  return ctx;
}

struct LitVoxel {
  Vec3 centre, velocity;
  int lit = 0;
};

// The lit voxels of frame `f` of a finished run: their count, and the
// world centre and velocity of the last one.
LitVoxel FrameLeaf(const std::filesystem::path& dir, uint64_t f) {
  LitVoxel out;
  const auto path = dir / server::FrameFileName("one", f);
  auto d = ReadVdbFile(path);
  auto v = ReadVec3VdbFile(path, "v");
  EXPECT_TRUE(d.ok() && v.ok()) << path;
  if (!d.ok() || !v.ok()) return out;
  const Int3 r = d->frame.resolution;
  for (int x = 0; x < r.x; ++x)
    for (int y = 0; y < r.y; ++y)
      for (int z = 0; z < r.z; ++z) {
        if (!(d->At(x, y, z) > 0)) continue;
        ++out.lit;
        out.centre = {d->origin_center.x + x * d->voxel_size.x,
                      d->origin_center.y + y * d->voxel_size.y,
                      d->origin_center.z + z * d->voxel_size.z};
        out.velocity = v->At(x, y, z);
      }
  return out;
}

// Dropped from 1.5 m (dt = 10 ms) onto a ground at 0.5 with radius 0.1 and
// no bounce: frame f (n = 10 f steps) is at 1.5 - g·dt²·n(n+1)/2 until the
// step the fall reaches 0.6, then rests at 0.6; the velocity grid holds
// the frame-to-frame difference times the frame rate.
TEST(JellyRunner, ADroppedBodyFallsAndRestsWhereTheClosedFormSays) {
  const v1::JobSpec spec = OneBody(
      R"({"radius": 0.1, "scale": {"uniform": 0.5}, "position": {"y": 1.5}})",
      R"("ground": {"height": 0.5, "restitution": 0, "friction": 0})",
      R"({"resolution": [4, 200, 4], "bounds_min": {"x": -0.02, "y": 0, "z": -0.02},
          "bounds_max": {"x": 0.02, "y": 2, "z": 0.02}})",
      10, 10);
  const auto ctx = RunOneBody(spec);
  const auto dir = server::ExtraFilesDir(ctx->result());
  const double g = 9.81, dt = 0.01;
  const uint64_t land = nimbus::testing::SymplecticLandingStep(1.5, 0.6, g, dt);
  ASSERT_GT(land, 40u);
  ASSERT_LT(land, 50u);
  auto height = [&](uint64_t n) {
    return n < land ? nimbus::testing::SymplecticFallHeight(1.5, g, dt, n) : 0.6;
  };
  for (uint64_t f = 0; f < 10; ++f) {
    SCOPED_TRACE(::testing::Message() << "frame " << f);
    const LitVoxel leaf = FrameLeaf(dir, f);
    ASSERT_EQ(leaf.lit, 1);
    EXPECT_NEAR(leaf.centre.y, height(10 * f), 0.005 + 1e-6);
    EXPECT_NEAR(leaf.centre.x, 0, 0.005 + 1e-6);
    const double vy = f == 0 ? 0 : (height(10 * f) - height(10 * (f - 1))) * 10;
    EXPECT_NEAR(leaf.velocity.y, vy, 1e-4);
  }
}

// A body of mass 1 on an anchored spring of k = 4 (ω = 2 rad/s), released
// 0.3 from the anchor with no gravity: x(t) = 0.3·cos(2t); 1.5 s is most
// of a half period, so the body swings through the anchor to the far side.
TEST(JellyRunner, ABodyOnASpringSwingsAsTheHarmonicOscillator) {
  const v1::JobSpec spec = OneBody(
      R"({"scale": {"uniform": 0.5}, "position": {"x": 0.3, "y": 1}})",
      R"("gravity": {}, "springs": [{"body_a": 0, "anchor": {"y": 1}, "rest_length": 0,
          "stiffness": 4}])",
      R"({"resolution": [80, 4, 4], "bounds_min": {"x": -0.4, "y": 0.98, "z": -0.02},
          "bounds_max": {"x": 0.4, "y": 1.02, "z": 0.02}})",
      16, 50);
  const auto ctx = RunOneBody(spec);
  const auto dir = server::ExtraFilesDir(ctx->result());
  for (uint64_t f = 0; f < 16; ++f) {
    SCOPED_TRACE(::testing::Message() << "frame " << f);
    const LitVoxel leaf = FrameLeaf(dir, f);
    ASSERT_EQ(leaf.lit, 1);
    // Half a voxel, plus symplectic Euler's amplitude error 0.3·ω·dt/2.
    EXPECT_NEAR(leaf.centre.x, 0.3 * std::cos(2 * 0.1 * double(f)), 0.005 + 0.002);
  }
}

// A spec impulse J = 0.2 on a body of mass 2 at rest, with no gravity,
// shown first by frame 3: the body stays until frame 2, then moves at
// J/m = 0.1 m/s, 1 cm per frame at 10 fps, and the velocity grid says so.
TEST(JellyRunner, ASpecImpulseStartsTheBodyAtImpulseOverMass) {
  const v1::JobSpec spec = OneBody(
      R"({"mass": 2, "scale": {"uniform": 0.5}, "position": {"y": 1}})",
      R"("gravity": {}, "impulses": [{"frame": 3, "push": {"body": 0, "impulse": {"x": 0.2}}}])",
      R"({"resolution": [16, 2, 2], "bounds_min": {"x": -0.01, "y": 0.995, "z": -0.005},
          "bounds_max": {"x": 0.07, "y": 1.005, "z": 0.005}})",
      8, 10);
  const auto ctx = RunOneBody(spec);
  const auto dir = server::ExtraFilesDir(ctx->result());
  for (uint64_t f = 0; f < 8; ++f) {
    SCOPED_TRACE(::testing::Message() << "frame " << f);
    const LitVoxel leaf = FrameLeaf(dir, f);
    ASSERT_EQ(leaf.lit, 1);
    const double x = f < 3 ? 0 : 0.01 * double(f - 2);
    EXPECT_NEAR(leaf.centre.x, x, 0.0025 + 1e-6);
    EXPECT_NEAR(leaf.velocity.x, f < 3 ? 0 : 0.1, 1e-5);
  }
}

}  // namespace
}  // namespace nimbus::spec
