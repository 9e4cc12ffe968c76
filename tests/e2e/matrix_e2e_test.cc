// An IFS-matrix job through the service, in process: submit the tree
// example (smaller), watch it finish, fetch the file and read both grids;
// a bad reference comes back as INVALID_ARGUMENT naming the field.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "client/nimbus_client.h"
#include "core/matrix/component_grid.h"
#include "core/io/vdb_io.h"
#include "proto/spec_io.h"
#include "server/server.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

using ::testing::HasSubstr;

class MatrixE2e : public ::testing::Test {
 protected:
  void SetUp() override {
    server::ServerOptions options;
    options.listen = "";
    options.data_dir = dir_ / "data";
    options.workers = 1;
    options.threads_per_job = 2;
    auto s = server::NimbusServer::Start(options);
    ASSERT_TRUE(s.ok()) << s.status();
    server_ = *std::move(s);
    client_ = std::make_unique<client::NimbusClient>(server_->InProcessChannel());
  }
  void TearDown() override {
    client_.reset();
    if (server_) server_->Shutdown();
  }

  v1::JobSpec Tree() {
    auto spec = spec::LoadSpecFile(testing::SourcePath("examples/tree_matrix.json"));
    EXPECT_TRUE(spec.ok()) << spec.status();
    spec->mutable_grid()->set_resolution(0, 5);
    spec->mutable_grid()->set_resolution(1, 96);
    spec->mutable_grid()->set_resolution(2, 90);
    spec->mutable_chaos_game()->set_iterations(2000000);
    return *spec;
  }

  testing::TempDir dir_;
  std::unique_ptr<server::NimbusServer> server_;
  std::unique_ptr<client::NimbusClient> client_;
};

TEST_F(MatrixE2e, TreeJobWritesDensityAndComponents) {
  auto job = client_->Submit(Tree());
  ASSERT_TRUE(job.ok()) << job.status();
  auto done = client_->Watch(job->id(), {}, [](const v1::WatchJobResponse&) {});
  ASSERT_TRUE(done.ok()) << done.status();
  ASSERT_EQ(done->state(), v1::JOB_STATE_SUCCEEDED) << done->DebugString();
  EXPECT_EQ(done->stats().at("matrix_size"), 2u);
  // The job ran in its own task arena of --threads-per-job threads.
  EXPECT_EQ(done->stats().at("arena_threads"), 2u);
  EXPECT_EQ(done->stats().at("matrix_components"), 3u);
  bool sized = false;
  for (const auto& w : done->warnings()) sized |= w.find("H_tree: 2x2") != std::string::npos;
  EXPECT_TRUE(sized);

  ASSERT_TRUE(client_->Fetch(job->id(), dir_ / "tree.vdb").ok());
  auto density = ReadVdbFile(dir_ / "tree.vdb", "density");
  ASSERT_TRUE(density.ok()) << density.status();
  auto labels = ReadComponentGrid(dir_ / "tree.vdb", density->frame.resolution);
  ASSERT_TRUE(labels.ok()) << labels.status();
  std::vector<int> seen(3, 0);
  for (size_t v = 0; v < labels->size(); ++v) {
    ASSERT_EQ((*labels)[v] >= 0, density->values[v] > 0);
    if ((*labels)[v] >= 0) seen[size_t((*labels)[v])] = 1;
  }
  EXPECT_EQ(seen, (std::vector<int>{1, 1, 1}));
  // COMPONENT_GRID_INT: the result holds the ids as floats (readable by
  // pyopenvdb and Blender); the Int32 grid is a further file of the result.
  ASSERT_EQ(done->result().files_size(), 1);
  EXPECT_EQ(done->result().files(0).file_name(), "tree_matrix.component.vdb");
  ASSERT_TRUE(
      client_->Fetch(job->id(), dir_ / "ids.vdb", "tree_matrix.component.vdb").ok());
  auto ints = ReadComponentGrid(dir_ / "ids.vdb", density->frame.resolution);
  ASSERT_TRUE(ints.ok()) << ints.status();
  EXPECT_EQ(*ints, *labels);
}

TEST_F(MatrixE2e, UnknownMapIsRefusedAtSubmit) {
  v1::JobSpec spec = Tree();
  spec.mutable_chaos_game()
      ->mutable_matrices()
      ->mutable_matrices(0)
      ->mutable_rows(0)
      ->mutable_entries(0)
      ->set_maps(1, "T7");
  auto job = client_->Submit(spec);
  ASSERT_EQ(job.status().code(), absl::StatusCode::kInvalidArgument) << job.status();
  EXPECT_THAT(std::string(job.status().message()),
              HasSubstr("chaos_game.matrices.matrices[0].rows[0].entries[0].maps[1]"));
  EXPECT_THAT(std::string(job.status().message()), HasSubstr("'T7'"));
}

}  // namespace
}  // namespace nimbus
