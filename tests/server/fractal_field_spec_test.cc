// Fractal-field specs through the converter (every error names its field,
// sizes refused before anything is built), the memory price, and the runner
// with a fake job context: frames, terrains, PNG height maps, byte-identical
// results for any thread count, and JobSpec.detail on another kind's result.
#include <gtest/gtest.h>
#include <tbb/task_arena.h>

#include <cmath>
#include <fstream>
#include <sstream>

#include "core/base/sha256.h"
#include "core/field/field_render.h"
#include "core/io/png_io.h"
#include "core/io/metadata_keys.h"
#include "core/io/vdb_io.h"
#include "proto/spec_convert.h"
#include "proto/spec_io.h"
#include "server/job_runner.h"
#include "server/memory_admission.h"
#include "server/result_store.h"
#include "tests/support/fake_job_context.h"
#include "tests/support/test_util.h"

namespace nimbus::spec {
namespace {

using nimbus::testing::FakeJobContext;
using nimbus::testing::SourcePath;

v1::JobSpec Parse(const std::string& json) {
  auto spec = ParseSpec(json, SpecFormat::kJson);
  EXPECT_TRUE(spec.ok()) << spec.status();
  return spec.ok() ? *spec : v1::JobSpec();
}

// A small looping cloud: 4D field, wind over a periodic x axis.
v1::JobSpec Loop(int frames = 4) {
  return Parse(R"({
    "name": "loop",
    "grid": {"resolution": [24, 20, 16], "bounds_min": {"x": 0, "y": 0, "z": 0},
             "bounds_max": {"x": 2, "y": 2, "z": 1}},
    "fractal_field": {
      "field": {
        "dimensions": 4,
        "mesh_series": {"base_cell_size": [0.5, 0.5, 0.5, 1], "ratio": 0.5, "count": 4},
        "weights": {"rule": "WEIGHT_RULE_POWER", "hurst": 0.7},
        "interpolation": "FIELD_INTERPOLATION_PSEUDO_CUBIC",
        "seed": "5",
        "mapping": {"wind": {"kind": "WIND_KIND_LINEAR", "velocity": [-0.5]}, "period": [2, 2]}
      },
      "density": {"threshold": -0.2, "gain": 2},
      "animation": {"frames": )" +
               std::to_string(frames) + R"(, "time_step": 1, "loop": true}
    }
  })");
}

std::string Error(const v1::JobSpec& spec, const Limits& limits = {}) {
  auto job = ConvertSpec(spec, limits);
  return job.ok() ? "ok" : std::string(job.status().message());
}

std::string FileBytes(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

v1::FieldSource* Field(v1::JobSpec& spec) {
  return spec.mutable_fractal_field()->mutable_field();
}

TEST(FractalFieldSpec, ExamplesConvert) {
  for (const char* name : {"cumulus", "terrain", "earthquake", "wind_loop"}) {
    auto spec = LoadSpecFile(SourcePath(std::string("examples/") + name + ".json"));
    ASSERT_TRUE(spec.ok()) << name << ": " << spec.status();
    if (spec->fractal_field().has_shape())  // the CLI resolves paths beside the spec
      spec->mutable_fractal_field()->mutable_shape()->mutable_source()->mutable_mesh()
          ->mutable_asset()->set_path(SourcePath("examples/meshes/suzanne.obj").string());
    auto job = ConvertSpec(*spec, {});
    ASSERT_TRUE(job.ok()) << name << ": " << job.status();
    ASSERT_NE(job->fractal_field(), nullptr);
    EXPECT_EQ(KindName(job->kind), "fractal_field");
  }
}

TEST(FractalFieldSpec, LoopSetsTheTimePeriod) {
  auto job = ConvertSpec(Loop(), {});
  ASSERT_TRUE(job.ok()) << job.status();
  const FractalFieldPlan& k = *job->fractal_field();
  EXPECT_EQ(k.field.mapping.period[3], 4.0);  // frames * time_step
  for (const FieldMesh& m : k.field.meshes) {
    EXPECT_GT(m.period_nodes[0], 0);
    EXPECT_GT(m.period_nodes[3], 0);
    EXPECT_EQ(m.period_nodes[2], 0);
  }
  EXPECT_EQ(job->work.total, 4u);
  EXPECT_EQ(job->work.unit, "frames");
}

TEST(FractalFieldSpec, ErrorsNameTheField) {
  struct Case {
    std::function<void(v1::JobSpec&)> mutate;
    std::string message;
  };
  const std::vector<Case> cases = {
      {[](v1::JobSpec& s) { Field(s)->set_dimensions(0); },
       "fractal_field.field.dimensions: must be 1..4, got 0"},
      {[](v1::JobSpec& s) { Field(s)->set_dimensions(2); },
       "fractal_field.field.dimensions: a density volume needs 3 (or 4 with time) dimensions, got 2"},
      {[](v1::JobSpec& s) {
         Field(s)->clear_mesh_series();
         Field(s)->add_meshes()->add_cell_size(1);
         Field(s)->add_meshes()->add_cell_size(0);
       },
       "fractal_field.field.meshes[1].cell_size[0]: must be >= 1e-09 (a cell needs a size), got 0"},
      {[](v1::JobSpec& s) {
         Field(s)->clear_mesh_series();
         for (int i = 0; i < 65; ++i) Field(s)->add_meshes()->add_cell_size(1);
       },
       "fractal_field.field.meshes: at most 64 meshes, got 65"},
      {[](v1::JobSpec& s) { Field(s)->mutable_mesh_series()->set_count(65); },
       "fractal_field.field.mesh_series.count: must be 1..64, got 65"},
      {[](v1::JobSpec& s) { Field(s)->mutable_mesh_series()->set_ratio(1.5); },
       "fractal_field.field.mesh_series.ratio: must be in (0, 1), got 1.5"},
      {[](v1::JobSpec& s) {
         auto* w = Field(s)->mutable_weights();
         w->set_rule(v1::WEIGHT_RULE_EXPLICIT);
         for (double v : {1.0, 0.5, std::nan(""), 0.1}) w->add_explicit_weights(v);
       },
       "fractal_field.field.weights.explicit_weights[2]: must be finite, got nan"},
      {[](v1::JobSpec& s) {
         auto* w = Field(s)->mutable_weights();
         w->set_rule(v1::WEIGHT_RULE_EXPLICIT);
         w->add_explicit_weights(1);
       },
       "fractal_field.field.weights: weights.explicit: needs one weight per mesh (4), got 1"},
      {[](v1::JobSpec& s) { s.mutable_fractal_field()->mutable_animation()->set_frames(5000); },
       "fractal_field.animation.frames: at most 4096 frames, got 5000"},
      {[](v1::JobSpec& s) { Field(s)->mutable_mapping()->mutable_wind()->set_velocity(0, -0.3); },
       "fractal_field.field.mapping.wind.velocity[0]: moves the field -1.2 per loop, not a whole "
       "number of periods (2)"},
      {[](v1::JobSpec& s) { Field(s)->mutable_mapping()->clear_period(); },
       "fractal_field.field.mapping.period[0]: a looping wind needs this axis to be periodic"},
      {[](v1::JobSpec& s) { s.mutable_fractal_field()->mutable_terrain(); },
       "fractal_field: set at most one of density and terrain"},
      {[](v1::JobSpec& s) { Field(s)->mutable_mapping()->add_period(-1); },
       "fractal_field.field.mapping.period[2]: must be 0 (not periodic) or >= 1e-09, got -1"},
      {[](v1::JobSpec& s) { Field(s)->mutable_mapping()->add_period(1e-320); },
       "fractal_field.field.mapping.period[2]: must be 0 (not periodic) or >= 1e-09, got "
       "9.99989e-321"},
      {[](v1::JobSpec& s) {
         auto* wind = Field(s)->mutable_mapping()->mutable_wind();
         wind->set_kind(v1::WIND_KIND_SINE);
         wind->set_period(1e-320);
       },
       "fractal_field.field.mapping.wind.period: must be in [1e-09, 1e+12] time units (0: 1), "
       "got 9.99989e-321"},
      {[](v1::JobSpec& s) {
         auto* w = Field(s)->mutable_weights();
         w->set_rule(v1::WEIGHT_RULE_EXPLICIT);
         for (int i = 0; i < 4; ++i) w->add_explicit_weights(i == 2 ? -0.0 : 0.0);
       },
       "fractal_field.field.weights.explicit_weights: need at least one weight that is not 0"},
      {[](v1::JobSpec& s) { Field(s)->mutable_weights()->set_amplitude(-1e-310); },
       "fractal_field.field.weights.amplitude: too close to 0 to weigh anything, got -1e-310"},
      {[](v1::JobSpec& s) { s.mutable_fractal_field()->mutable_density()->set_gain(-1); },
       "fractal_field.density.gain: must be finite and > 0, got -1"},
      {[](v1::JobSpec& s) { s.mutable_fractal_field()->mutable_density()->set_gain(1e-300); },
       "fractal_field.density.gain: must be at least 1.17549e-38 (smaller densities round to 0), "
       "got 1e-300"},
      {[](v1::JobSpec& s) { s.mutable_fractal_field()->mutable_density()->set_threshold(1); },
       "fractal_field.density.threshold: must be < 1 without a shape (the field lies in [-1, 1], "
       "so every voxel would be empty), got 1"},
      {[](v1::JobSpec& s) {
         Field(s)->clear_mesh_series();
         auto* m = Field(s)->add_meshes();
         m->add_cell_size(0.5);
         m->set_rotation_degrees(30);
         m->mutable_rotation_axis()->set_z(1);
       },
       "fractal_field.field.meshes[0].rotation_degrees: a rotated mesh cannot repeat along axis 0 "
       "(mapping.period is set)"},
      {[](v1::JobSpec& s) { s.mutable_fractal_field()->mutable_shape(); },
       "fractal_field.shape.source: required"},
      {[](v1::JobSpec& s) { s.mutable_fractal_field()->clear_field(); },
       "fractal_field.field: required"},
  };
  for (const Case& c : cases) {
    v1::JobSpec spec = Loop();
    c.mutate(spec);
    EXPECT_EQ(Error(spec), c.message);
  }
}

TEST(FractalFieldSpec, DetailErrorsNameTheField) {
  v1::JobSpec spec = Loop();
  auto* d = spec.mutable_detail()->mutable_field();
  d->set_dimensions(4);
  d->mutable_mesh_series()->add_base_cell_size(0.5);
  d->mutable_mesh_series()->set_count(2);
  EXPECT_EQ(Error(spec), "detail.field.dimensions: detail on a volume needs 3 dimensions, got 4");
  d->set_dimensions(3);
  spec.mutable_detail()->set_strength(std::nan(""));
  EXPECT_EQ(Error(spec), "detail.strength: must be finite and within ±1e12, got nan");
}

TEST(FractalFieldSpec, AbsurdGridsAreRefusedBeforeAllocation) {
  v1::JobSpec spec = Loop();
  spec.mutable_grid()->clear_resolution();
  spec.mutable_grid()->add_resolution(4000);
  Limits limits;
  EXPECT_EQ(Error(spec, limits), "grid.resolution: 64000000000 voxels exceed the server limit of "
                                 "8589934592");
  spec.mutable_grid()->set_resolution(0, 1500);
  limits.max_memory_bytes = uint64_t{1} << 30;
  auto job = ConvertSpec(spec, limits);
  ASSERT_TRUE(job.ok()) << job.status();  // structurally fine...
  auto m = server::AdmitMemory(*job, limits, 2);
  ASSERT_FALSE(m.ok());  // ...but priced out, before anything is built
  EXPECT_EQ(m.status().code(), absl::StatusCode::kResourceExhausted);
  EXPECT_NE(m.status().message().find("grid.resolution: the fractal field needs up to"),
            std::string::npos)
      << m.status();
}

// Runs `spec` on `threads` engine threads; returns the context (files stay
// in its temp dir).
std::unique_ptr<FakeJobContext> RunSpec(const v1::JobSpec& spec, int threads) {
  auto job = ConvertSpec(spec, {});
  EXPECT_TRUE(job.ok()) << job.status();
  auto ctx = std::make_unique<FakeJobContext>();
  ctx->threads_ = threads;
  tbb::task_arena arena(threads);
  absl::Status st;
  arena.execute([&] { st = server::RunJobPlan(*job, *ctx); });
  EXPECT_TRUE(st.ok()) << st;
  return ctx;
}

TEST(FractalFieldRunner, FramesAreByteIdenticalForAnyThreadCount) {
  const v1::JobSpec spec = Loop(4);
  auto one = RunSpec(spec, 1);
  auto two = RunSpec(spec, 2);
  const auto dir1 = server::ExtraFilesDir(one->result());
  const auto dir2 = server::ExtraFilesDir(two->result());
  for (int f = 1; f <= 4; ++f) {
    const std::string name = "loop.000" + std::to_string(f) + ".vdb";
    ASSERT_TRUE(std::filesystem::exists(dir1 / name)) << name;
    EXPECT_EQ(Sha256Hex(FileBytes(dir1 / name)), Sha256Hex(FileBytes(dir2 / name))) << name;
  }
  EXPECT_FALSE(std::filesystem::exists(dir1 / "loop.0005.vdb"));
  // The main result is frame 1.
  EXPECT_EQ(FileBytes(one->result()), FileBytes(dir1 / "loop.0001.vdb"));
  auto vol = ReadVdbFile(one->result());
  ASSERT_TRUE(vol.ok()) << vol.status();
  EXPECT_EQ(vol->grid_class, "fog volume");
  const MetaValue* frame = vol->Find(meta_key::kFieldFrame);
  ASSERT_NE(frame, nullptr);
  EXPECT_EQ(std::get<int64_t>(*frame), 1);
  EXPECT_TRUE(one->progress_ordered);
  EXPECT_EQ(one->Last(server::JobPhase::kIterating).done, 4u);
}

TEST(FractalFieldRunner, ConsecutiveFramesDifferAndTheLoopCloses) {
  // 4 frames: frame 5 would be frame 1. Render 5 frames of the same field
  // without the loop's renumbering by asking for a longer loop is not the
  // same spec, so check the engine directly: frame index 4 is frame 0.
  auto job = ConvertSpec(Loop(4), {});
  ASSERT_TRUE(job.ok());
  const FractalFieldPlan& k = *job->fractal_field();
  FractalField f(k.field);
  auto a = RenderDensity(f, k, job->frame, FrameTime(k.animation, 0), nullptr);
  auto b = RenderDensity(f, k, job->frame, FrameTime(k.animation, 4), nullptr);
  auto c = RenderDensity(f, k, job->frame, FrameTime(k.animation, 1), nullptr);
  ASSERT_TRUE(a.ok() && b.ok() && c.ok());
  EXPECT_EQ(a->values, b->values);
  EXPECT_NE(a->values, c->values);
}

TEST(FractalFieldRunner, TerrainWritesLevelSetAndPng) {
  v1::JobSpec spec = Parse(R"({
    "name": "hills",
    "grid": {"resolution": [40, 32, 16]},
    "fractal_field": {
      "field": {"dimensions": 2, "mesh_series": {"base_cell_size": [1], "count": 5},
                "weights": {"rule": "WEIGHT_RULE_POWER", "hurst": 0.8}, "seed": "3"},
      "terrain": {"base_height": 0, "height_scale": 0.5}
    }
  })");
  auto ctx = RunSpec(spec, 2);
  auto surface = ReadVdbFile(ctx->result(), "surface");
  ASSERT_TRUE(surface.ok()) << surface.status();
  EXPECT_EQ(surface->grid_class, "level set");
  auto png = ReadPng16(server::ExtraFilesDir(ctx->result()) / "hills.height.png");
  ASSERT_TRUE(png.ok()) << png.status();
  EXPECT_EQ(png->width, 40);
  EXPECT_EQ(png->height, 32);
  // The PNG holds the same heights: recompute them with the engine.
  auto job = ConvertSpec(spec, {});
  const FractalFieldPlan& k = *job->fractal_field();
  auto h = RenderHeights(FractalField(k.field), k, job->frame, 0);
  ASSERT_TRUE(h.ok());
  const Gray16Image expected = HeightMap16(*h);
  EXPECT_EQ(png->pixels, expected.pixels);
  // Below the surface the level set is negative, above positive.
  const int x = 20, y = 16;
  const double hz = h->heights[size_t(x) * 32 + y];
  const Vec3 vs = job->frame.VoxelSize();
  for (int z = 0; z < 16; ++z) {
    const double zc = job->frame.bounds.min.z + (z + 0.5) * vs.z;
    const float v = surface->At(x, y, z);
    if (zc < hz - 1e-6 && v != 0) {
      EXPECT_LT(v, 0) << z;
    }
    if (zc > hz + 1e-6 && v != 0) {
      EXPECT_GT(v, 0) << z;
    }
  }
}

TEST(FractalFieldRunner, ShapedCloudFollowsTheShape) {
  v1::JobSpec spec = Parse(R"({
    "name": "ball",
    "grid": {"resolution": [32]},
    "fractal_field": {
      "field": {"dimensions": 3, "mesh_series": {"base_cell_size": [0.5], "count": 4}, "seed": "2"},
      "density": {"gain": 4},
      "shape": {"source": {"sphere": {"radius": 0.5}}, "falloff": 0.1, "detail": 0.3}
    }
  })");
  auto ctx = RunSpec(spec, 2);
  auto vol = ReadVdbFile(ctx->result());
  ASSERT_TRUE(vol.ok());
  EXPECT_GT(vol->At(16, 16, 16), 0.5f);   // deep inside: dense
  EXPECT_EQ(vol->At(1, 1, 1), 0.0f);      // far outside: empty
}

TEST(FractalFieldDetail, ModulatesAnotherKindsDensity) {
  auto base = LoadSpecFile(SourcePath("examples/sierpinski_tetrahedron.json"));
  ASSERT_TRUE(base.ok());
  base->mutable_grid()->set_resolution(0, 32);
  base->mutable_chaos_game()->set_iterations(200000);
  v1::JobSpec detailed = *base;
  auto* d = detailed.mutable_detail();
  d->set_strength(0.8);
  auto* f = d->mutable_field();
  f->set_dimensions(3);
  f->mutable_mesh_series()->add_base_cell_size(0.5);
  f->mutable_mesh_series()->set_count(3);
  f->set_seed(4);
  auto plain_job = ConvertSpec(*base, {});
  ASSERT_TRUE(plain_job.ok());
  EXPECT_FALSE(plain_job->density.modulation);  // unset: the old write path
  auto plain = RunSpec(*base, 2);
  auto mod = RunSpec(detailed, 2);
  auto a = ReadVdbFile(plain->result());
  auto b = ReadVdbFile(mod->result());
  ASSERT_TRUE(a.ok() && b.ok());
  // Oracle: the same field through the point evaluator.
  auto job = ConvertSpec(detailed, {});
  ASSERT_TRUE(job.ok());
  int checked = 0, changed = 0;
  for (int x = 0; x < 32; ++x)
    for (int y = 0; y < 32; ++y)
      for (int z = 0; z < 32; ++z) {
        const float p = a->At(x, y, z);
        if (p == 0) continue;
        const double m = job->density.modulation(job->frame.VoxelCenter({x, y, z}));
        EXPECT_NEAR(b->At(x, y, z), p * std::max(0.0, m), 1e-6);
        ++checked;
        changed += std::abs(m - 1) > 1e-3;
      }
  EXPECT_GT(checked, 100);
  EXPECT_GT(changed, checked / 2);
}

}  // namespace
}  // namespace nimbus::spec
