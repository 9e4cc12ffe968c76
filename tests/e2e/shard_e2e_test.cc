// Sharded jobs and the result cache through a real nimbusd with two
// workers (docs/sharding.md, docs/result_cache.md): a job split into S
// shards writes the very bytes of the unsharded job, for a coloured
// nonlinear chaos game and an IFS matrix; a failing shard fails its parent
// by name; cancelling the parent cancels the shards; a resubmitted spec is
// answered from the cache as a new job.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>

#include <chrono>
#include <filesystem>
#include <set>
#include <thread>

#include "core/base/sha256.h"
#include "tests/support/server_fixture.h"

namespace nimbus {
namespace {

using ::testing::HasSubstr;
using ::testing::MatchesRegex;

class ShardE2E : public ::testing::Test {
 protected:
  void SetUp() override {
    ASSERT_TRUE(server_.Start().ok());
    client_ = client::NimbusClient::Connect(server_.target());
    ASSERT_TRUE(client_->WaitForReady(20).ok()) << "nimbusd did not answer";
  }

  // The coloured flame of examples/flame_cloud.json, small: 8 chunks.
  static v1::JobSpec Flame() {
    v1::JobSpec spec = testing::LoadExample("flame_cloud.json");
    spec.mutable_grid()->set_resolution(0, 48);
    spec.mutable_chaos_game()->set_iterations(8 * (uint64_t{1} << 20) - 12345);
    spec.set_no_cache(true);
    return spec;
  }
  // The IFS-matrix tree, as one chain (no component grid): 8 chunks.
  static v1::JobSpec Tree() {
    v1::JobSpec spec = testing::LoadExample("tree_matrix.json");
    spec.mutable_grid()->set_resolution(0, 5);
    spec.mutable_grid()->set_resolution(1, 64);
    spec.mutable_grid()->set_resolution(2, 60);
    spec.mutable_chaos_game()->mutable_matrices()->clear_component_grid();
    spec.mutable_chaos_game()->set_iterations(8 * (uint64_t{1} << 20));
    spec.set_no_cache(true);
    return spec;
  }

  // Submits, follows the job to its end and returns its final view.
  v1::Job RunToEnd(const v1::JobSpec& spec, client::WatchOptions watch = {},
                   std::function<void(const v1::WatchJobResponse&)> on_update = nullptr) {
    auto job = client_->Submit(spec);
    EXPECT_TRUE(job.ok()) << job.status();
    if (!job.ok()) return {};
    auto done = client_->Watch(job->id(), watch,
                               on_update ? on_update : [](const v1::WatchJobResponse&) {});
    EXPECT_TRUE(done.ok()) << done.status();
    return done.ok() ? *done : v1::Job();
  }
  // The sha256 of a succeeded job's fetched file.
  std::string FetchedSha(const v1::Job& job) {
    const auto path = dir_ / (job.id() + ".vdb");
    EXPECT_TRUE(client_->Fetch(job.id(), path).ok());
    auto sha = Sha256File(path);
    EXPECT_TRUE(sha.ok());
    return sha.ok() ? *sha : "";
  }
  // Files of shard partials left in the result store.
  int PartialsLeft() {
    int n = 0;
    for (const auto& e : std::filesystem::directory_iterator(dir_ / "data" / "results"))
      n += e.path().filename().string().find(".shard-") != std::string::npos;
    return n;
  }
  // S = 1 is the unsharded run asked for explicitly.
  void ExpectShardsMatch(const v1::JobSpec& base) {
    const v1::Job whole = RunToEnd(base);
    ASSERT_EQ(whole.state(), v1::JOB_STATE_SUCCEEDED) << whole.error();
    EXPECT_EQ(whole.shards(), 0u);
    const std::string expected = FetchedSha(whole);
    for (uint32_t s : {1u, 3u, 8u}) {
      v1::JobSpec sharded = base;
      sharded.set_shards(s);
      const v1::Job job = RunToEnd(sharded);
      ASSERT_EQ(job.state(), v1::JOB_STATE_SUCCEEDED) << job.error();
      EXPECT_EQ(job.shards(), s > 1 ? s : 0);
      EXPECT_EQ(job.shards_succeeded(), s > 1 ? s : 0);
      EXPECT_EQ(job.result().sha256(), whole.result().sha256()) << "S = " << s;
      EXPECT_EQ(FetchedSha(job), expected) << "S = " << s;
      EXPECT_EQ(PartialsLeft(), 0) << "the merge deletes the partials";
    }
  }

  testing::TempDir dir_;
  testing::NimbusdProcess server_{
      dir_ / "data", {"--workers", "2", "--threads-per-job", "1", "--log-level", "warn"}};
  std::unique_ptr<client::NimbusClient> client_;
};

TEST_F(ShardE2E, AColouredFlameShardedIsByteIdentical) { ExpectShardsMatch(Flame()); }

TEST_F(ShardE2E, AnIfsMatrixShardedIsByteIdentical) { ExpectShardsMatch(Tree()); }

TEST_F(ShardE2E, WatchersOfTheParentSeeShardProgressAndPreviews) {
  v1::JobSpec spec = Flame();
  spec.set_shards(3);
  client::WatchOptions watch;
  watch.preview_resolution = 16;
  watch.preview_interval_seconds = 0.05;
  uint64_t last_done = 0, previews = 0;
  bool running = false;
  const v1::Job done = RunToEnd(spec, watch, [&](const v1::WatchJobResponse& r) {
    if (r.has_preview()) ++previews;
    if (r.job().state() != v1::JOB_STATE_RUNNING) return;
    running = true;
    EXPECT_EQ(r.job().shards(), 3u);
    // The most seen: the merge's own phase starts again from 0.
    last_done = std::max<uint64_t>(last_done, r.job().progress().done());
  });
  ASSERT_EQ(done.state(), v1::JOB_STATE_SUCCEEDED) << done.error();
  EXPECT_TRUE(running);
  EXPECT_GT(last_done, 0u);
  EXPECT_GE(previews, 1u);
  // The shards are not listed.
  auto list = client_->List({});
  ASSERT_TRUE(list.ok());
  for (const v1::Job& j : list->jobs()) EXPECT_THAT(j.id(), ::testing::Not(HasSubstr(".shard-")));
}

TEST_F(ShardE2E, AFailingShardFailsTheParentByName) {
  v1::JobSpec spec = Flame();
  spec.mutable_grid()->set_resolution(0, 96);
  spec.mutable_chaos_game()->set_iterations(24 * (uint64_t{1} << 20));
  spec.set_shards(3);
  auto job = client_->Submit(spec);
  ASSERT_TRUE(job.ok()) << job.status();
  // A folder where shard 2's partial must go: its commit fails.
  std::filesystem::create_directories(dir_ / "data" / "results" / (job->id() + ".shard-2.vdb"));
  auto done = client_->Watch(job->id(), {}, [](const v1::WatchJobResponse&) {});
  ASSERT_TRUE(done.ok()) << done.status();
  EXPECT_EQ(done->state(), v1::JOB_STATE_FAILED);
  EXPECT_THAT(done->error(), MatchesRegex("shard 2 of 3: .*"));
  EXPECT_EQ(done->status().message(), done->error());
}

TEST_F(ShardE2E, CancellingTheParentCancelsItsShards) {
  v1::JobSpec spec = Flame();
  spec.mutable_grid()->set_resolution(0, 96);
  spec.mutable_chaos_game()->set_iterations(400 * (uint64_t{1} << 20));
  spec.set_shards(4);
  auto job = client_->Submit(spec);
  ASSERT_TRUE(job.ok()) << job.status();
  // Wait until two shards run.
  for (int i = 0; i < 200; ++i) {
    auto now = client_->Get(job->id());
    if (now.ok() && now->state() == v1::JOB_STATE_RUNNING) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  auto cancelled = client_->Cancel(job->id());
  ASSERT_TRUE(cancelled.ok()) << cancelled.status();
  EXPECT_EQ(cancelled->state(), v1::JOB_STATE_CANCELLED);
  for (uint32_t k = 0; k < 4; ++k) {
    const std::string id = job->id() + ".shard-" + std::to_string(k);
    auto shard = client_->Watch(id, {}, [](const v1::WatchJobResponse&) {});
    ASSERT_TRUE(shard.ok()) << shard.status();
    EXPECT_EQ(shard->state(), v1::JOB_STATE_CANCELLED) << id;
  }
  auto after = client_->Get(job->id());
  ASSERT_TRUE(after.ok());
  EXPECT_EQ(after->state(), v1::JOB_STATE_CANCELLED);
  // A shard goes with its job only; deleting the job removes the shards
  // and what they wrote.
  EXPECT_EQ(client_->Delete(job->id() + ".shard-1").status().code(),
            absl::StatusCode::kFailedPrecondition);
  ASSERT_TRUE(client_->Delete(job->id()).ok());
  EXPECT_EQ(client_->Get(job->id() + ".shard-0").status().code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(PartialsLeft(), 0);
}

TEST_F(ShardE2E, ASpecRunTwiceIsAnsweredFromTheCache) {
  v1::JobSpec spec = Tree();
  spec.set_no_cache(false);
  spec.mutable_chaos_game()->set_iterations(2 * (uint64_t{1} << 20));
  const v1::Job first = RunToEnd(spec);
  ASSERT_EQ(first.state(), v1::JOB_STATE_SUCCEEDED);
  EXPECT_EQ(first.cached_from(), "");
  const std::string sha = FetchedSha(first);

  // The same spec (the shard count is not part of its hash): a new job,
  // finished at once, with a copy of the result.
  v1::JobSpec again = spec;
  again.set_shards(2);
  auto hit = client_->Submit(again);
  ASSERT_TRUE(hit.ok()) << hit.status();
  EXPECT_EQ(hit->state(), v1::JOB_STATE_SUCCEEDED);
  EXPECT_NE(hit->id(), first.id());
  EXPECT_EQ(hit->cached_from(), first.id());
  EXPECT_EQ(hit->result().sha256(), first.result().sha256());
  EXPECT_EQ(hit->progress().done(), hit->progress().total());
  // Each job's result lives on its own.
  ASSERT_TRUE(client_->Delete(first.id()).ok());
  EXPECT_EQ(FetchedSha(*hit), sha);

  // --no-cache runs it again; another spec misses.
  v1::JobSpec fresh = spec;
  fresh.set_no_cache(true);
  const v1::Job rerun = RunToEnd(fresh);
  ASSERT_EQ(rerun.state(), v1::JOB_STATE_SUCCEEDED);
  EXPECT_EQ(rerun.cached_from(), "");
  EXPECT_EQ(rerun.result().sha256(), first.result().sha256());
  v1::JobSpec other = spec;
  other.mutable_chaos_game()->set_seed(99);
  auto miss = client_->Submit(other);
  ASSERT_TRUE(miss.ok());
  EXPECT_EQ(miss->cached_from(), "");
  EXPECT_NE(miss->state(), v1::JOB_STATE_SUCCEEDED);
}

TEST_F(ShardE2E, ImpossibleShardingIsRefusedByFieldName) {
  v1::JobSpec spec = Flame();
  spec.set_shards(9);  // 8 chunks
  EXPECT_THAT(std::string(client_->Submit(spec).status().message()),
              HasSubstr("shards: must be at most the run's 8 chunks"));
  spec = Flame();
  spec.set_shards(2);
  spec.mutable_chaos_game()->mutable_convergence()->set_tolerance(0.01);
  EXPECT_THAT(std::string(client_->Submit(spec).status().message()),
              HasSubstr("shards: cannot be combined with chaos_game.convergence"));
  spec = Tree();
  spec.set_shards(2);
  spec.mutable_chaos_game()->mutable_matrices()->set_component_grid(v1::COMPONENT_GRID_INT);
  EXPECT_THAT(std::string(client_->Submit(spec).status().message()),
              HasSubstr("shards: cannot be combined with chaos_game.matrices.component_grid"));
  spec = testing::LoadExample("terrain.json");
  spec.set_shards(2);
  auto refused = client_->Submit(spec);
  EXPECT_EQ(refused.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(std::string(refused.status().message()), HasSubstr("shards: applies to chaos_game"));
}

}  // namespace
}  // namespace nimbus

namespace nimbus {
namespace {

TEST(ShardAutoE2E, AServerSplitsBigJobsItself) {
  testing::TempDir dir;
  // Jobs above 2 chunks are split into shards of about 2 chunks.
  testing::NimbusdProcess server(
      dir / "data", {"--workers", "2", "--threads-per-job", "1", "--log-level", "warn",
                     "--auto-shard-iterations", std::to_string(2 * (uint64_t{1} << 20))});
  ASSERT_TRUE(server.Start().ok());
  auto client = client::NimbusClient::Connect(server.target());
  ASSERT_TRUE(client->WaitForReady(20).ok());
  v1::JobSpec spec = testing::LoadExample("sierpinski_tetrahedron.json");
  spec.mutable_grid()->set_resolution(0, 64);
  spec.mutable_chaos_game()->set_iterations(7 * (uint64_t{1} << 20));
  spec.set_no_cache(true);
  auto run = [&](uint32_t shards) {
    v1::JobSpec s = spec;
    s.set_shards(shards);
    auto job = client->Submit(s);
    EXPECT_TRUE(job.ok()) << job.status();
    auto done = client->Watch(job->id(), {}, [](const v1::WatchJobResponse&) {});
    EXPECT_TRUE(done.ok());
    EXPECT_EQ(done->state(), v1::JOB_STATE_SUCCEEDED) << done->error();
    return *done;
  };
  const v1::Job split = run(0);  // 0: the server chooses
  EXPECT_EQ(split.shards(), 4u);
  const v1::Job whole = run(1);  // 1: never split
  EXPECT_EQ(whole.shards(), 0u);
  EXPECT_EQ(split.result().sha256(), whole.result().sha256());
}

}  // namespace
}  // namespace nimbus
