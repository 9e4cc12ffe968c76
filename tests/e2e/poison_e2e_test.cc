// Hostile input against a real nimbusd on loopback: damaged VDB grids and
// garbage meshes are refused at upload or submit with a message naming the
// field, huge names and ids are refused or cut, and the server keeps
// serving everyone else.
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <openvdb/openvdb.h>
#include <openvdb/tools/LevelSetSphere.h>

#include <fstream>
#include <sstream>

#include "client/nimbus_client.h"
#include "core/base/sha256.h"
#include "proto/asset_paths.h"
#include "proto/spec_io.h"
#include "tests/support/nimbusd_process.h"
#include "tests/support/server_fixture.h"
#include "tests/support/test_util.h"
#include "tests/support/vdb_fixtures.h"

namespace nimbus {
namespace {

using client::NimbusClient;
using ::testing::HasSubstr;
using ::testing::StartsWith;



v1::JobSpec CowCloud() {
  auto spec = spec::LoadSpecFile(testing::SourcePath("examples/cow_cloud.json"));
  EXPECT_TRUE(spec.ok()) << spec.status();
  v1::JobSpec s = *spec;
  s.mutable_grid()->set_resolution(0, 32);
  s.mutable_set_ifs()->mutable_random()->set_iterations(200);
  return s;
}

class PoisonE2E : public testing::NimbusdTest {
 protected:
  absl::StatusOr<v1::UploadAssetResponse> Upload(const std::string& name,
                                                 const std::string& bytes) {
    return client_->UploadBytes(name, bytes, Sha256Hex(bytes), bytes.size());
  }

  // The server still does real work: a small job from a good mesh succeeds.
  void ExpectAGoodJobRuns() {
    const std::string cow = testing::ReadFileBytes(testing::SourcePath("examples/meshes/cow.obj"));
    ASSERT_TRUE(Upload("cow.obj", cow).ok());
    v1::JobSpec spec = CowCloud();
    spec::ForEachAsset(spec, [&](const std::string&, v1::Asset& a) {
      a.set_sha256(Sha256Hex(cow));
      a.set_label("cow.obj");
    });
    auto job = client_->Submit(spec);
    ASSERT_TRUE(job.ok()) << job.status();
    auto done = client_->Watch(job->id(), {}, [](const v1::WatchJobResponse&) {});
    ASSERT_TRUE(done.ok()) << done.status();
    EXPECT_EQ(done->state(), v1::JOB_STATE_SUCCEEDED) << done->error();
    v1::ListJobsRequest list;
    auto page = client_->List(list);
    ASSERT_TRUE(page.ok()) << page.status();
    EXPECT_GE(page->jobs_size(), 1);
  }

};

TEST_F(PoisonE2E, DamagedVdbIsRefusedAtUploadAndAtSubmit) {
  const std::string vdb = testing::SphereVdbBytes(dir_ / "sphere.vdb");
  const std::string cut = vdb.substr(0, vdb.size() / 2);
  const std::string sha = Sha256Hex(cut);

  // Named as a grid, the upload is read in a sandbox and refused.
  auto refused = Upload("cow.vdb", cut);
  ASSERT_EQ(refused.status().code(), absl::StatusCode::kInvalidArgument) << refused.status();
  EXPECT_THAT(std::string(refused.status().message()),
              StartsWith("grid asset cow.vdb (sha256 " + sha.substr(0, 12) +
                         "...): not a readable VDB file: "));

  // Uploaded without a format, it is kept; a spec that reads it as a grid
  // is refused at submit, naming the field.
  ASSERT_TRUE(Upload("blob", cut).ok());
  // Its other assets uploaded: a network server never reads a path.
  const std::string cow = testing::ReadFileBytes(testing::SourcePath("examples/meshes/cow.obj"));
  ASSERT_TRUE(Upload("cow.obj", cow).ok());
  v1::JobSpec spec = CowCloud();
  spec::ForEachAsset(spec, [&](const std::string&, v1::Asset& a) { a.set_sha256(Sha256Hex(cow)); });
  v1::GridSource* grid =
      spec.mutable_set_ifs()->mutable_maps(0)->mutable_condensation()->mutable_grid();
  grid->mutable_asset()->set_sha256(sha);
  grid->mutable_asset()->set_label("cow.vdb");
  auto job = client_->Submit(spec);
  ASSERT_EQ(job.status().code(), absl::StatusCode::kInvalidArgument) << job.status();
  EXPECT_THAT(std::string(job.status().message()),
              StartsWith("set_ifs.maps[0].condensation.grid.asset: grid asset cow.vdb (sha256 " +
                         sha.substr(0, 12) + "...): not a readable VDB file: "));
  EXPECT_LT(job.status().message().size(), 1000u);

  // A bit flip in the grid's metadata (one that makes OpenVDB allocate
  // without end) costs the sandboxed reader, not the server.
  std::string flipped = vdb;
  flipped[130] = char(flipped[130] ^ 0xff);
  auto flip = Upload("flip.vdb", flipped);
  EXPECT_EQ(flip.status().code(), absl::StatusCode::kInvalidArgument) << flip.status();
  ExpectAGoodJobRuns();
}

// A file OpenVDB's reader reads without error in the checker but, through
// undefined behaviour, crashes a later read (found by the 10-minute fuzz
// run): nimbusd reads only the grids the checker re-wrote, so jobs using it
// run to an end, several times, and the server keeps serving.
TEST_F(PoisonE2E, GridAssetsAreReadOnlyFromTheCheckersCopy) {
  const std::string bad = testing::ReadFileBytes(
      testing::SourcePath("tests/fuzz/openvdb_inputs/passes_check_then_crashes_reader"));
  ASSERT_FALSE(bad.empty());
  const std::string cow = testing::ReadFileBytes(testing::SourcePath("examples/meshes/cow.obj"));
  ASSERT_TRUE(Upload("cow.obj", cow).ok());
  auto up = Upload("bad.vdb", bad);
  ASSERT_TRUE(up.ok()) << up.status();
  const std::filesystem::path stored = dir_ / "data" / "assets" / Sha256Hex(bad);
  EXPECT_TRUE(std::filesystem::exists(spec::LaunderedPath(stored)));
  v1::JobSpec spec = CowCloud();
  spec::ForEachAsset(spec, [&](const std::string&, v1::Asset& a) {
    a.set_sha256(Sha256Hex(cow));
    a.set_label("cow.obj");
  });
  v1::GridSource* grid =
      spec.mutable_set_ifs()->mutable_maps(0)->mutable_condensation()->mutable_grid();
  grid->mutable_asset()->set_sha256(Sha256Hex(bad));
  grid->mutable_asset()->set_label("bad.vdb");
  for (int i = 0; i < 3; ++i) {
    spec.set_name("bad_grid_" + std::to_string(i));
    auto job = client_->Submit(spec);
    ASSERT_TRUE(job.ok()) << job.status();
    auto done = client_->Watch(job->id(), {}, [](const v1::WatchJobResponse&) {});
    ASSERT_TRUE(done.ok()) << done.status();
    EXPECT_TRUE(done->state() == v1::JOB_STATE_SUCCEEDED || done->state() == v1::JOB_STATE_FAILED)
        << done->state();
  }
  ExpectAGoodJobRuns();
}

TEST_F(PoisonE2E, GarbageMeshIsRefusedAtUploadAndAtSubmit) {
  std::string garbage;
  for (int i = 0; i < 8192; ++i) garbage.push_back(char((i * 37 + 11) & 0xff));
  auto refused = Upload("cow.obj", garbage);
  ASSERT_EQ(refused.status().code(), absl::StatusCode::kInvalidArgument) << refused.status();
  EXPECT_THAT(std::string(refused.status().message()), HasSubstr(": not a readable mesh: "));

  ASSERT_TRUE(Upload("blob", garbage).ok());
  v1::JobSpec spec = CowCloud();
  spec::ForEachAsset(spec, [&](const std::string&, v1::Asset& a) {
    a.set_sha256(Sha256Hex(garbage));
    a.set_label("cow.obj");
  });
  auto job = client_->Submit(spec);
  ASSERT_EQ(job.status().code(), absl::StatusCode::kInvalidArgument) << job.status();
  EXPECT_THAT(std::string(job.status().message()),
              StartsWith("set_ifs.maps[0].condensation.mesh.asset: mesh asset cow.obj (sha256 "));
  ExpectAGoodJobRuns();
}

TEST_F(PoisonE2E, HugeNamesAndIdsAreRefusedOrCut) {
  v1::JobSpec spec = CowCloud();
  spec.set_name(std::string(10 << 20, 'n'));
  auto job = client_->Submit(spec);
  ASSERT_EQ(job.status().code(), absl::StatusCode::kInvalidArgument) << job.status().code();
  EXPECT_THAT(std::string(job.status().message()), StartsWith("name: "));
  EXPECT_LT(job.status().message().size(), 200u);
  spec.set_name(std::string(129, 'n'));
  EXPECT_EQ(client_->Submit(spec).status().code(), absl::StatusCode::kInvalidArgument);

  auto missing = client_->Get(std::string(100'000, 'i'));
  ASSERT_EQ(missing.status().code(), absl::StatusCode::kNotFound) << missing.status();
  EXPECT_LT(missing.status().message().size(), 200u);
  v1::ListJobsRequest list;
  list.set_page_token(std::string(100'000, 't'));
  auto page = client_->List(list);
  ASSERT_EQ(page.status().code(), absl::StatusCode::kInvalidArgument) << page.status();
  EXPECT_LT(page.status().message().size(), 200u);
  ExpectAGoodJobRuns();
}

}  // namespace
}  // namespace nimbus
