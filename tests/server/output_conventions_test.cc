// Output conventions (issue 14): up axis, half floats, automatic
// downsampling, the suggested shader density, and their validation, from
// the spec through a runner to the file read back.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <iostream>

#include "core/io/metadata_keys.h"
#include "core/io/vdb_io.h"
#include "proto/spec_convert.h"
#include "proto/spec_io.h"
#include "server/job_runner.h"
#include "tests/support/fake_job_context.h"
#include "tests/support/test_util.h"
#include "tests/support/volume_oracles.h"

namespace nimbus {
namespace {

using ::testing::HasSubstr;

// examples/tree.json on a smaller grid and budget (same bounds).
v1::JobSpec SmallTree() {
  auto spec = spec::LoadSpecFile(testing::SourcePath("examples/tree.json"));
  EXPECT_TRUE(spec.ok()) << spec.status();
  spec->mutable_grid()->clear_resolution();
  for (int r : {9, 128, 120}) spec->mutable_grid()->add_resolution(r);
  spec->mutable_chaos_game()->set_iterations(6'000'000);
  return *spec;
}

// Runs `spec` through the converter and its runner into `out`.
absl::Status Render(const v1::JobSpec& spec, const std::filesystem::path& out, int threads = 2) {
  auto plan = spec::ConvertSpec(spec, {});
  if (!plan.ok()) return plan.status();
  testing::FakeJobContext ctx(out);
  ctx.threads_ = threads;
  return server::RunJobPlan(*plan, ctx);
}

std::string MetaString(const DenseVolume& v, const char* key) {
  const MetaValue* m = v.Find(key);
  return m && std::holds_alternative<std::string>(*m) ? std::get<std::string>(*m) : "";
}
int64_t MetaInt(const DenseVolume& v, const char* key) {
  const MetaValue* m = v.Find(key);
  return m && std::holds_alternative<int64_t>(*m) ? std::get<int64_t>(*m) : -1;
}
double MetaDouble(const DenseVolume& v, const char* key) {
  const MetaValue* m = v.Find(key);
  return m && std::holds_alternative<double>(*m) ? std::get<double>(*m) : std::nan("");
}

// Renders the small tree as is to dir/plain.vdb, and with `edit` applied to
// its output options to dir/edited.vdb.
void RenderPlainAndEdited(const testing::TempDir& dir,
                          const std::function<void(v1::Output&)>& edit) {
  v1::JobSpec spec = SmallTree();
  ASSERT_TRUE(Render(spec, dir / "plain.vdb").ok());
  edit(*spec.mutable_output());
  ASSERT_TRUE(Render(spec, dir / "edited.vdb").ok());
}

TEST(OutputConventions, ZUpStandsTheTreeTrunkAlongPlusZ) {
  testing::TempDir dir;
  RenderPlainAndEdited(dir, [](v1::Output& o) { o.set_up_axis(v1::UP_AXIS_Z); });
  auto y = ReadVdbFile(dir / "plain.vdb");
  auto z = ReadVdbFile(dir / "edited.vdb");
  ASSERT_TRUE(y.ok() && z.ok()) << y.status() << z.status();
  EXPECT_EQ(MetaString(*y, meta_key::kUpAxis), "Y");
  EXPECT_EQ(MetaString(*z, meta_key::kUpAxis), "Z");
  // The voxels are the same; only world space turned.
  EXPECT_EQ(y->values, z->values);
  EXPECT_EQ(z->frame.resolution, y->frame.resolution);

  // The spec's tree: trunk base at y = 0, crown up to y ~ 1.8, thin in x.
  const testing::WorldSpread sy = testing::ActiveWorldSpread(*y);
  const testing::WorldSpread sz = testing::ActiveWorldSpread(*z);
  const double height = sy.box.max.y - sy.box.min.y;
  EXPECT_GT(height, 1.5);
  // In the Z-up file the height is along +Z, from the ground up...
  EXPECT_NEAR(sz.box.min.z, sy.box.min.y, 1e-9);
  EXPECT_NEAR(sz.box.max.z, sy.box.max.y, 1e-9);
  EXPECT_GT(sz.centroid.z, 0.3);
  // ...the spec's z (the crown's width) along -Y, and x unchanged.
  EXPECT_NEAR(sz.box.min.y, -sy.box.max.z, 1e-9);
  EXPECT_NEAR(sz.box.max.y, -sy.box.min.z, 1e-9);
  EXPECT_NEAR(sz.box.min.x, sy.box.min.x, 1e-9);
  EXPECT_NEAR(sz.centroid.z, sy.centroid.y, 1e-9);
  EXPECT_NEAR(sz.centroid.y, -sy.centroid.z, 1e-9);
  // A proper rotation (right-handed): +Y index axis maps to +Z world.
  const Affine3& m = z->index_to_world;
  EXPECT_GT(m.Determinant(), 0);
  EXPECT_GT(m.m[2][1], 0);
  EXPECT_EQ(m.m[0][1], 0);
  EXPECT_EQ(m.m[1][1], 0);
}

TEST(OutputConventions, DefaultAndExplicitYGiveTheSameBytes) {
  testing::TempDir dir;
  RenderPlainAndEdited(dir, [](v1::Output& o) { o.set_up_axis(v1::UP_AXIS_Y); });
  EXPECT_EQ(testing::ReadFileBytes(dir / "plain.vdb"), testing::ReadFileBytes(dir / "edited.vdb"));
}

TEST(OutputConventions, HalfFloatRoundTripsWithinHalfPrecision) {
  testing::TempDir dir;
  RenderPlainAndEdited(dir, [](v1::Output& o) { o.set_half_float(true); });
  auto f = ReadVdbFile(dir / "plain.vdb");
  auto h = ReadVdbFile(dir / "edited.vdb");
  ASSERT_TRUE(f.ok() && h.ok());
  ASSERT_EQ(f->values.size(), h->values.size());
  size_t differing = 0;
  for (size_t i = 0; i < f->values.size(); ++i) {
    const float a = f->values[i], b = h->values[i];
    // 11 significant bits: relative error at most 2^-11 for normal halves,
    // an absolute 2^-25 below them.
    EXPECT_LE(std::abs(a - b), std::max(std::abs(a) * 0x1p-11f, 0x1p-25f)) << i;
    differing += a != b;
  }
  EXPECT_GT(differing, 0u) << "the file really holds halves";
  EXPECT_LT(std::filesystem::file_size(dir / "edited.vdb"),
            std::filesystem::file_size(dir / "plain.vdb"));
}

TEST(OutputConventions, MaxVoxelsDownsamplesKeepingMass) {
  testing::TempDir dir;
  v1::JobSpec fine_spec = SmallTree();
  ASSERT_TRUE(Render(fine_spec, dir / "fine.vdb").ok());
  auto fine = ReadVdbFile(dir / "fine.vdb");
  ASSERT_TRUE(fine.ok());
  const uint64_t fine_active = testing::CoarseActiveVoxels(*fine, 1);
  ASSERT_GT(fine_active, 2000u);
  EXPECT_EQ(MetaInt(*fine, meta_key::kDownsampleFactor), 1);

  const int64_t limit = std::max<int64_t>(512, int64_t(fine_active / 10));
  v1::JobSpec spec = fine_spec;
  spec.mutable_output()->set_max_voxels(limit);
  ASSERT_TRUE(Render(spec, dir / "coarse.vdb").ok());
  auto coarse = ReadVdbFile(dir / "coarse.vdb");
  ASSERT_TRUE(coarse.ok());
  const int f = int(MetaInt(*coarse, meta_key::kDownsampleFactor));
  ASSERT_GE(f, 2);
  // The smallest factor that fits, by an independent count.
  EXPECT_EQ(testing::CoarseActiveVoxels(*fine, f), testing::CoarseActiveVoxels(*coarse, 1));
  EXPECT_LE(testing::CoarseActiveVoxels(*coarse, 1), uint64_t(limit));
  EXPECT_GT(testing::CoarseActiveVoxels(*fine, f - 1), uint64_t(limit));
  // The coarse lattice covers the fine one; mass is kept.
  EXPECT_EQ(coarse->frame.resolution.y, (fine->frame.resolution.y + f - 1) / f);
  EXPECT_NEAR(coarse->voxel_size.y, f * fine->voxel_size.y, 1e-12);
  EXPECT_NEAR(testing::Mass(*coarse), testing::Mass(*fine), 1e-5 * testing::Mass(*fine));
  // The total count still describes the whole run.
  EXPECT_EQ(MetaInt(*coarse, "nimbus_total_count"), MetaInt(*fine, "nimbus_total_count"));
}

TEST(OutputConventions, TargetFileBytesBoundsTheEstimate) {
  testing::TempDir dir;
  // Denser than the tree: a Sierpinski tetrahedron at 256 fills 256² voxels.
  auto spec = spec::LoadSpecFile(testing::SourcePath("examples/sierpinski_tetrahedron.json"));
  ASSERT_TRUE(spec.ok());
  spec->mutable_chaos_game()->set_iterations(20'000'000);
  ASSERT_TRUE(Render(*spec, dir / "fine.vdb").ok());
  auto fine = ReadVdbFile(dir / "fine.vdb");
  ASSERT_TRUE(fine.ok());
  DensityOptions o;  // one float grid
  const GridSupport fine_support = testing::CoarseSupport(*fine, 1);
  const uint64_t fine_bytes = EstimatedFileBytes(fine_support, o);
  EXPECT_EQ(fine_bytes, kFileOverheadBytes + 4 * fine_support.voxels +
                            kLeafFileBytes * fine_support.leaves);
  // The estimate bounds the real file.
  EXPECT_LE(std::filesystem::file_size(dir / "fine.vdb"), fine_bytes);
  const int64_t target = std::max<int64_t>(65536, int64_t(fine_bytes / 4));
  ASSERT_GT(fine_bytes, uint64_t(target));
  spec->mutable_output()->set_target_file_bytes(target);
  ASSERT_TRUE(Render(*spec, dir / "t.vdb").ok());
  auto v = ReadVdbFile(dir / "t.vdb");
  ASSERT_TRUE(v.ok());
  const int f = int(MetaInt(*v, meta_key::kDownsampleFactor));
  EXPECT_GE(f, 2);
  EXPECT_LE(EstimatedFileBytes(testing::CoarseSupport(*v, 1), o), uint64_t(target));
  EXPECT_GT(EstimatedFileBytes(testing::CoarseSupport(*fine, f - 1), o), uint64_t(target));
  EXPECT_LE(std::filesystem::file_size(dir / "t.vdb"), uint64_t(target));
  std::cerr << "target " << target << " bytes: factor " << f << ", file "
            << std::filesystem::file_size(dir / "t.vdb") << " bytes (full "
            << std::filesystem::file_size(dir / "fine.vdb") << ")\n";
}

TEST(OutputConventions, SuggestedDensityFollowsItsFormula) {
  testing::TempDir dir;
  ASSERT_TRUE(Render(SmallTree(), dir / "t.vdb").ok());
  auto v = ReadVdbFile(dir / "t.vdb");
  ASSERT_TRUE(v.ok());
  const double got = MetaDouble(*v, meta_key::kSuggestedDensity);
  ASSERT_TRUE(std::isfinite(got));
  EXPECT_GE(got, 1.0);
  EXPECT_LE(got, 1000.0);
  const uint64_t n = testing::CoarseActiveVoxels(*v, 1);
  double sum = 0;
  for (float d : v->values) sum += d;
  const double h = std::cbrt(v->voxel_size.x * v->voxel_size.y * v->voxel_size.z);
  const double want = std::clamp(kSuggestedDepth / (sum / double(n) * h * std::cbrt(double(n))),
                                 1.0, 1000.0);
  EXPECT_NEAR(got, want, 1e-6 * want);
  EXPECT_EQ(SuggestedDensity(0, 0, 1), 1.0);
}

TEST(OutputConventions, SameBytesWhateverTheThreadCount) {
  testing::TempDir dir;
  v1::JobSpec spec = SmallTree();
  spec.mutable_output()->set_up_axis(v1::UP_AXIS_Z);
  spec.mutable_output()->set_half_float(true);
  spec.mutable_output()->set_max_voxels(2000);
  ASSERT_TRUE(Render(spec, dir / "1.vdb", 1).ok());
  ASSERT_TRUE(Render(spec, dir / "2.vdb", 2).ok());
  EXPECT_EQ(testing::ReadFileBytes(dir / "1.vdb"), testing::ReadFileBytes(dir / "2.vdb"));
}

absl::Status ConvertWith(const std::function<void(v1::Output&)>& edit) {
  v1::JobSpec spec = SmallTree();
  edit(*spec.mutable_output());
  return spec::ConvertSpec(spec, {}).status();
}

TEST(OutputConventions, BadValuesAreRefusedByFieldPath) {
  auto s = ConvertWith([](v1::Output& o) { o.set_up_axis(static_cast<v1::UpAxis>(7)); });
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(s.message(), HasSubstr("output.up_axis: unknown value 7"));
  s = ConvertWith([](v1::Output& o) { o.set_max_voxels(-5); });
  EXPECT_THAT(s.message(), HasSubstr("output.max_voxels: must be 0 (no limit) or in [512, "));
  s = ConvertWith([](v1::Output& o) { o.set_max_voxels(100); });
  EXPECT_THAT(s.message(), HasSubstr("got 100"));
  s = ConvertWith([](v1::Output& o) { o.set_max_voxels(int64_t{1} << 41); });
  EXPECT_THAT(s.message(), HasSubstr("output.max_voxels"));
  s = ConvertWith([](v1::Output& o) { o.set_target_file_bytes(-1); });
  EXPECT_THAT(s.message(), HasSubstr("output.target_file_bytes: must be 0 (no limit)"));
  s = ConvertWith([](v1::Output& o) { o.set_target_file_bytes(1000); });
  EXPECT_THAT(s.message(), HasSubstr("output.target_file_bytes"));
  EXPECT_TRUE(ConvertWith([](v1::Output& o) {
                o.set_max_voxels(512);
                o.set_target_file_bytes(65536);
              }).ok());

  // A component grid cannot be box-filtered: refused by name.
  auto spec = spec::LoadSpecFile(testing::SourcePath("examples/tree_matrix.json"));
  ASSERT_TRUE(spec.ok());
  ASSERT_NE(spec->chaos_game().matrices().component_grid(), v1::COMPONENT_GRID_NONE);
  spec->mutable_output()->set_max_voxels(10000);
  s = spec::ConvertSpec(*spec, {}).status();
  EXPECT_THAT(s.message(), HasSubstr("output.max_voxels: not supported together with"));
}

}  // namespace
}  // namespace nimbus
