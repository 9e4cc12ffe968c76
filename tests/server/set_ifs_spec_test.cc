// Conversion of set_ifs specs: sources, maps, probabilities, budgets, and
// errors that name the offending field (and file).
#include <gtest/gtest.h>

#include <cmath>
#include <fstream>

#include "absl/strings/str_format.h"
#include "core/grid/count_grid.h"
#include "core/base/sha256.h"
#include "core/io/vdb_io.h"
#include "core/sets/set_ifs_plan.h"
#include "proto/asset_paths.h"
#include "server/memory_admission.h"
#include "proto/spec_convert.h"
#include "proto/spec_io.h"
#include "server/job_runner.h"
#include "server/result_store.h"
#include "tests/support/fake_job_context.h"
#include "tests/support/test_util.h"

namespace nimbus::spec {
namespace {

std::string Mesh(const std::string& name) {
  return nimbus::testing::SourcePath("examples/meshes/" + name).string();
}

// The mesh asset of set_ifs.maps[map]'s condensation.
v1::Asset* MeshAsset(v1::JobSpec& spec, int map) {
  return spec.mutable_set_ifs()
      ->mutable_maps(map)
      ->mutable_condensation()
      ->mutable_mesh()
      ->mutable_asset();
}

v1::JobSpec TwoSpheres() {
  v1::JobSpec spec;
  spec.mutable_grid()->add_resolution(32);
  v1::SetIfs* s = spec.mutable_set_ifs();
  auto* a = s->add_maps();
  a->set_probability(2);
  a->mutable_condensation()->mutable_sphere()->set_radius(0.4);
  auto* b = s->add_maps();
  b->set_probability(1);
  b->mutable_condensation()->mutable_sphere()->mutable_center()->set_x(0.5);
  b->mutable_condensation()->mutable_sphere()->set_radius(0.2);
  s->mutable_random()->set_iterations(100);
  return spec;
}

std::string Error(const v1::JobSpec& spec, const Limits& limits = {}) {
  auto job = ConvertSpec(spec, limits);
  return job.ok() ? "ok" : std::string(job.status().message());
}

TEST(SetIfsSpec, ConvertsMapsProbabilitiesAndBudget) {
  auto job = ConvertSpec(TwoSpheres(), {});
  ASSERT_TRUE(job.ok()) << job.status();
  ASSERT_NE(job->set_ifs(), nullptr);
  const SetIfsPlan& p = *job->set_ifs();
  ASSERT_EQ(p.maps.size(), 2u);
  EXPECT_NEAR(p.probabilities[0], 2.0 / 3, 1e-12);
  EXPECT_NEAR(p.probabilities[1], 1.0 / 3, 1e-12);
  EXPECT_EQ(p.labels, (std::vector<std::string>{"A", "B"}));
  EXPECT_EQ(p.maps[0].kind, SetMapKind::kMedian);
  EXPECT_FALSE(p.book);
  EXPECT_EQ(p.warmup, 16u);
  // Warm-up is preparation; progress counts the 100 counted iterations.
  EXPECT_EQ(job->work.total, 100u);
  EXPECT_EQ(job->work.unit, "set iterations");
  auto memory = server::AdmitMemory(*job, {}, 2);
  ASSERT_TRUE(memory.ok()) << memory.status();
  EXPECT_GT(memory->estimated_bytes, CountGrid::MaxMemoryBytes(job->frame.resolution));
}

TEST(SetIfsSpec, MixesEveryKindOfMap) {
  v1::JobSpec spec = TwoSpheres();
  v1::SetIfs* s = spec.mutable_set_ifs();
  s->mutable_maps(0)->set_kind(v1::SET_MAP_KIND_ROTATED_MEDIAN);
  s->mutable_maps(0)->mutable_rotation()->set_degrees_per_unit(45);
  s->mutable_maps(0)->mutable_rotation()->mutable_axis()->set_y(1);
  s->mutable_maps(1)->set_kind(v1::SET_MAP_KIND_CONSTANT);
  auto* point = s->add_maps();
  point->mutable_point()->add_steps()->mutable_scale()->set_uniform(0.5);
  auto job = ConvertSpec(spec, {});
  ASSERT_TRUE(job.ok()) << job.status();
  const SetIfsPlan& p = *job->set_ifs();
  EXPECT_EQ(p.maps[0].kind, SetMapKind::kRotatedMedian);
  EXPECT_DOUBLE_EQ(p.maps[0].rotated.degrees_per_unit, 45);
  EXPECT_EQ(p.maps[1].kind, SetMapKind::kConstant);
  EXPECT_EQ(p.maps[2].kind, SetMapKind::kPoint);
  ASSERT_TRUE(p.maps[2].point.has_value());
  // No probabilities at all: equal.
  for (auto& m : *s->mutable_maps()) m.set_probability(0);
  job = ConvertSpec(spec, {});
  ASSERT_TRUE(job.ok());
  EXPECT_NEAR(job->set_ifs()->probabilities[2], 1.0 / 3, 1e-12);
}

TEST(SetIfsSpec, ErrorsNameTheField) {
  v1::JobSpec spec = TwoSpheres();
  spec.mutable_set_ifs()->mutable_maps(1)->clear_condensation();
  EXPECT_EQ(Error(spec), "set_ifs.maps[1].condensation: required");

  spec = TwoSpheres();
  spec.mutable_set_ifs()->mutable_maps(1)->mutable_condensation()->mutable_sphere()->set_radius(0);
  EXPECT_NE(Error(spec).find("set_ifs.maps[1].condensation.sphere.radius"), std::string::npos);

  spec = TwoSpheres();
  spec.mutable_set_ifs()->mutable_maps(0)->set_probability(-1);
  EXPECT_NE(Error(spec).find("set_ifs.maps[0].probability"), std::string::npos);

  spec = TwoSpheres();
  spec.mutable_set_ifs()->mutable_random()->set_iterations(0);
  EXPECT_NE(Error(spec).find("set_ifs.random.iterations"), std::string::npos);

  spec = TwoSpheres();
  spec.mutable_set_ifs()->mutable_book()->set_depth(13);
  EXPECT_NE(Error(spec).find("set_ifs.book.depth"), std::string::npos);

  spec = TwoSpheres();
  spec.mutable_grid()->set_resolution(0, 1500);
  EXPECT_NE(Error(spec).find("1024"), std::string::npos);

  spec = TwoSpheres();
  spec.mutable_set_ifs()->mutable_maps(0)->mutable_rotation()->set_degrees_per_unit(3);
  EXPECT_NE(Error(spec).find("set_ifs.maps[0].rotation"), std::string::npos);

  spec = TwoSpheres();
  auto* balls =
      spec.mutable_set_ifs()->mutable_maps(0)->mutable_condensation()->mutable_random_balls();
  balls->mutable_inside()->mutable_mesh();
  EXPECT_EQ(Error(spec), "set_ifs.maps[0].condensation.random_balls.inside.mesh.asset: required");
}

TEST(SetIfsSpec, AssetsByPathAndBySha256) {
  v1::JobSpec spec = TwoSpheres();
  v1::Asset* asset = MeshAsset(spec, 0);
  asset->set_path("/no/such/cow.obj");
  EXPECT_NE(Error(spec).find("set_ifs.maps[0].condensation.mesh.asset.path: no such file"),
            std::string::npos);
  asset->set_path(Mesh("cow.obj"));
  EXPECT_EQ(Error(spec), "ok");
  Limits remote;
  remote.allow_local_paths = false;
  EXPECT_EQ(Error(spec, remote),
            "set_ifs.maps[0].condensation.mesh.asset.path: this server never opens files named "
            "in a spec; upload the file and give its sha256 instead (the nimbus CLI does this)");

  // By hash: found in the asset folder under <sha256>.obj.
  nimbus::testing::TempDir dir;
  std::ifstream in(Mesh("cow.obj"), std::ios::binary);
  const std::string bytes((std::istreambuf_iterator<char>(in)), {});
  const std::string sha = Sha256Hex(bytes);
  remote.asset_dir = dir.path();
  asset->set_sha256(sha);
  EXPECT_NE(Error(spec, remote).find("no uploaded asset"), std::string::npos);
  std::ofstream(dir / (sha + ".obj"), std::ios::binary) << bytes;
  EXPECT_EQ(Error(spec, remote), "ok");
  asset->set_sha256("ABC");
  EXPECT_NE(Error(spec, remote).find("asset.sha256: must be 64"), std::string::npos);
}

TEST(SetIfsSpec, BadMeshesAreClearErrorsNamingFieldAndFile) {
  nimbus::testing::TempDir dir;
  const auto nan = dir / "nan.obj";
  std::ofstream(nan) << "v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n";
  const auto empty = dir / "empty.obj";
  std::ofstream(empty) << "# nothing\n";
  const auto flat = dir / "flat.obj";
  std::ofstream(flat) << "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n";
  for (const auto& file : {nan, empty, flat}) {
    v1::JobSpec spec = TwoSpheres();
    MeshAsset(spec, 1)->set_path(file.string());
    const std::string e = Error(spec);
    EXPECT_NE(e.find("set_ifs.maps[1].condensation.mesh"), std::string::npos) << e;
    EXPECT_NE(e.find(file.filename().string()), std::string::npos) << e;
  }
}

TEST(SetIfsSpec, NonWatertightMeshWarns) {
  v1::JobSpec spec = TwoSpheres();
  MeshAsset(spec, 0)->set_path(Mesh("teapot.obj"));
  auto job = ConvertSpec(spec, {});
  ASSERT_TRUE(job.ok()) << job.status();
  ASSERT_EQ(job->warnings.size(), 1u);
  EXPECT_NE(job->warnings[0].find("not watertight"), std::string::npos);
  EXPECT_NE(job->warnings[0].find("set_ifs.maps[0].condensation.mesh"), std::string::npos);
}

TEST(SetIfsSpec, BuildsSourcesOnTheGrid) {
  v1::JobSpec spec = TwoSpheres();
  auto* c = spec.mutable_set_ifs()->mutable_maps(0)->mutable_condensation();
  auto* balls = c->mutable_random_balls();
  balls->mutable_inside()->mutable_sphere()->set_radius(0.6);
  balls->set_count(5);
  balls->set_clip_to_region(true);
  auto* u = spec.mutable_set_ifs()->mutable_maps(1)->mutable_condensation()->mutable_union_();
  u->add_parts()->mutable_box()->mutable_max()->set_x(0.5);
  u->mutable_parts(0)->mutable_box()->mutable_max()->set_y(0.5);
  u->mutable_parts(0)->mutable_box()->mutable_max()->set_z(0.5);
  u->add_parts()->mutable_torus()->set_major_radius(0.5);
  u->mutable_parts(1)->mutable_torus()->set_minor_radius(0.1);
  auto job = ConvertSpec(spec, {});
  ASSERT_TRUE(job.ok()) << job.status();
  SetBuildCache cache;
  auto region = BuildSetSource(job->set_ifs()->maps[0].condensation->parts[0], job->frame, &cache);
  auto set = BuildSetSource(*job->set_ifs()->maps[0].condensation, job->frame, &cache);
  ASSERT_TRUE(region.ok() && set.ok());
  EXPECT_GT(set->Count(), 0);
  EXPECT_TRUE((*set - *region).Empty());  // clipped to the region
  auto uni = BuildSetSource(*job->set_ifs()->maps[1].condensation, job->frame, &cache);
  ASSERT_TRUE(uni.ok()) << uni.status();
  EXPECT_GT(uni->Count(), 0);
  EXPECT_EQ(cache.sets.size(), 5u);  // region, balls, box, torus, union

  // A sketch outside the bounds is an error naming the source.
  auto far = spec;
  far.mutable_set_ifs()
      ->mutable_maps(1)
      ->mutable_condensation()
      ->mutable_sphere()
      ->mutable_center()
      ->set_x(5);
  far.mutable_set_ifs()->mutable_maps(1)->mutable_condensation()->mutable_sphere()->set_radius(0.1);
  auto job2 = ConvertSpec(far, {});
  ASSERT_TRUE(job2.ok());
  auto none = BuildSetSource(*job2->set_ifs()->maps[1].condensation, job2->frame, nullptr);
  EXPECT_NE(none.status().message().find("set_ifs.maps[1].condensation"), std::string::npos)
      << none.status();
}

TEST(SetIfsSpec, MeshesAreFittedIntoTheGrid) {
  v1::JobSpec spec = TwoSpheres();
  MeshAsset(spec, 0)->set_path(Mesh("suzanne.obj"));
  auto job = ConvertSpec(spec, {});
  ASSERT_TRUE(job.ok()) << job.status();
  auto set = BuildSetSource(*job->set_ifs()->maps[0].condensation, job->frame, nullptr);
  ASSERT_TRUE(set.ok()) << set.status();
  auto box = set->BoundingBox();
  ASSERT_TRUE(box.has_value());
  // Scaled uniformly to fill the grid but for a 2-voxel margin on its
  // longest axis, and centred on every axis (voxel indices 0..31, so the
  // centre is 15.5).
  const Int3 size = box->Size();
  const int longest = size.x >= size.y && size.x >= size.z ? 0 : (size.y >= size.z ? 1 : 2);
  EXPECT_GE(size[longest], 27);
  EXPECT_LE(size[longest], 28);
  EXPECT_GE(box->min[longest], 2);
  EXPECT_LE(box->max[longest], 29);
  for (int a = 0; a < 3; ++a) EXPECT_LE(std::abs(box->min[a] + box->max[a] - 31), 1) << "axis " << a;
}

TEST(SetIfsSpec, ResolveAssetPathsIsRelativeToTheSpecFolder) {
  auto spec = LoadSpecFile(nimbus::testing::SourcePath("examples/cow_cloud.json"));
  ASSERT_TRUE(spec.ok());
  ResolveAssetPaths(*spec, "/some/folder");
  std::vector<std::string> seen;
  ForEachAsset(*spec, [&](const std::string& field, v1::Asset& a) {
    seen.push_back(field + "=" + a.path());
  });
  EXPECT_EQ(seen, (std::vector<std::string>{
                      "set_ifs.maps[0].condensation.mesh.asset=/some/folder/meshes/cow.obj",
                      "set_ifs.maps[1].condensation.random_balls.inside.mesh.asset=/some/folder/"
                      "meshes/cow.obj"}));
}

TEST(SetIfsSpec, GridSourcesReadVdbFiles) {
  nimbus::testing::TempDir dir;
  v1::JobSpec spec = TwoSpheres();
  auto job = ConvertSpec(spec, {});
  ASSERT_TRUE(job.ok());
  // A fog volume of the first sphere, read back as the second map's set.
  auto ball = BuildSetSource(*job->set_ifs()->maps[0].condensation, job->frame, nullptr);
  ASSERT_TRUE(ball.ok());
  CountGrid counts(job->frame.resolution);
  ball->ForEach([&](int x, int y, int z) { counts.Add(x, y, z); });
  ASSERT_TRUE(WriteDensityVdb(dir / "ball.vdb", counts, job->frame, {}, {}).ok());
  auto* grid = spec.mutable_set_ifs()->mutable_maps(1)->mutable_condensation()->mutable_grid();
  grid->mutable_asset()->set_path((dir / "ball.vdb").string());
  job = ConvertSpec(spec, {});
  ASSERT_TRUE(job.ok()) << job.status();
  auto read = BuildSetSource(*job->set_ifs()->maps[1].condensation, job->frame, nullptr);
  ASSERT_TRUE(read.ok()) << read.status();
  EXPECT_EQ(*read, *ball);
  grid->set_grid_name("nope");
  job = ConvertSpec(spec, {});
  ASSERT_TRUE(job.ok());
  read = BuildSetSource(*job->set_ifs()->maps[1].condensation, job->frame, nullptr);
  EXPECT_NE(read.status().message().find("set_ifs.maps[1].condensation"), std::string::npos);
  EXPECT_NE(read.status().message().find("nope"), std::string::npos) << read.status();
}

TEST(SetIfsSpec, BookBudget) {
  v1::JobSpec spec = TwoSpheres();
  spec.mutable_set_ifs()->mutable_book()->set_depth(5);
  auto job = ConvertSpec(spec, {});
  ASSERT_TRUE(job.ok()) << job.status();
  EXPECT_TRUE(job->set_ifs()->book);
  EXPECT_EQ(job->set_ifs()->pages, 32u);
  EXPECT_EQ(job->work.total, 32u);
}

// The runner reports phases in order: preparing (one unit per map, the
// start set, then the warm-up), iterating over the counted iterations only,
// then writing; the density it writes sums every counted set.
TEST(SetIfsRunner, ReportsPhasesWithoutWarmupInTheTotal) {
  v1::JobSpec spec = TwoSpheres();
  spec.mutable_set_ifs()->mutable_random()->set_iterations(40);
  spec.mutable_set_ifs()->mutable_random()->set_warmup(12);
  auto job = ConvertSpec(spec, {});
  ASSERT_TRUE(job.ok()) << job.status();
  nimbus::testing::FakeJobContext ctx;
  ASSERT_TRUE(server::RunJobPlan(*job, ctx).ok());
  EXPECT_TRUE(ctx.progress_ordered);
  ASSERT_FALSE(ctx.progress.empty());
  EXPECT_EQ(ctx.progress.front().phase, server::JobPhase::kPreparing);
  const auto prep = ctx.Last(server::JobPhase::kPreparing);
  EXPECT_EQ(prep.total, 4u);  // 2 maps, the start set, the warm-up
  EXPECT_GE(prep.done, 3u);   // both maps and the start set were reported built
  const auto iter = ctx.Last(server::JobPhase::kIterating);
  EXPECT_EQ(iter.total, 40u);
  EXPECT_EQ(iter.unit, "set iterations");
  EXPECT_EQ(ctx.Last(server::JobPhase::kWriting).done, 1u);
  EXPECT_EQ(ctx.stats["set_iterations"], 52u);  // warm-up included in the engine's count
  auto density = ReadVdbFile(ctx.result());
  ASSERT_TRUE(density.ok()) << density.status();
}

// A book writes its pages as numbered frames beside the result.
TEST(SetIfsRunner, BookPagesAreNumberedFrames) {
  v1::JobSpec spec = TwoSpheres();
  spec.set_name("twospheres");
  spec.mutable_set_ifs()->mutable_book()->set_depth(2);
  auto job = ConvertSpec(spec, {});
  ASSERT_TRUE(job.ok()) << job.status();
  nimbus::testing::FakeJobContext ctx;
  ASSERT_TRUE(server::RunJobPlan(*job, ctx).ok());
  const std::filesystem::path frames = server::ExtraFilesDir(ctx.result());
  for (int page = 1; page <= 4; ++page) {
    auto file = frames / absl::StrFormat("twospheres.%04d.vdb", page);
    auto grid = ReadVdbFile(file);
    EXPECT_TRUE(grid.ok()) << file << ": " << grid.status();
  }
  EXPECT_FALSE(std::filesystem::exists(frames / "twospheres.0005.vdb"));
  EXPECT_EQ(ctx.Last(server::JobPhase::kIterating).done, 4u);
  EXPECT_EQ(ctx.Last(server::JobPhase::kIterating).unit, "pages");
}

}  // namespace
}  // namespace nimbus::spec
