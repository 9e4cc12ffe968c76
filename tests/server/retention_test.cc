// Ownership, quotas' accounting and retention in the stores, with a clock
// the test sets: owners filter listings, usage counts what quotas need,
// pins and deletes behave, and a sweep expires exactly the unpinned old
// results and the unused old assets.
#include "server/retention.h"

#include <gtest/gtest.h>

#include <chrono>
#include <filesystem>
#include <fstream>

#include "core/base/sha256.h"
#include "nimbus/v1/spec.pb.h"
#include "server/asset_store.h"
#include "server/job_store.h"
#include "server/result_store.h"
#include "tests/support/result_fixtures.h"
#include "tests/support/test_util.h"

namespace nimbus::server {
namespace {

constexpr TimeMs kT0 = 1'700'000'000'000;
constexpr int64_t kHour = 3'600'000;

class RetentionTest : public testing::LocalStoresTest {
 protected:
  void SetUp() override {
    LocalStoresTest::SetUp();
    auto assets = AssetStore::Open(dir_ / "assets");
    ASSERT_TRUE(assets.ok());
    assets_ = std::move(*assets);
  }

  void Create(const std::string& id, const std::string& owner, TimeMs now,
              const std::string& spec = "spec") {
    NewJob job;
    job.id = id;
    job.name = id;
    job.spec = spec + id;
    job.owner = owner;
    ASSERT_TRUE(store_->Create(job, now).ok());
  }

  // Runs the oldest queued job to success at `end` with a real result file
  // of `size` bytes.
  void Succeed(TimeMs end, size_t size) {
    const auto id = testing::SucceedNext(*store_, *results_, std::string(size, 'v'), end);
    ASSERT_TRUE(id.ok()) << id.status();
  }

  std::string Upload(const std::string& data, const std::string& owner) {
    const std::string sha = Sha256Hex(data);
    auto u = assets_->Begin(sha, data.size(), "blob.bin", owner);
    EXPECT_TRUE(u.ok()) << u.status();
    EXPECT_TRUE((*u)->Append(data).ok());
    EXPECT_TRUE((*u)->Finish().ok());
    return sha;
  }

  std::unique_ptr<AssetStore> assets_;
};

TEST_F(RetentionTest, OwnersFilterListingsAndUsageCountsActiveJobsAndResults) {
  Create("a", "alice", kT0);
  Create("b", "bob", kT0 + 1);
  Create("c", "alice", kT0 + 2);
  ListOptions mine;
  mine.owner = "alice";
  auto page = store_->List(mine);
  ASSERT_TRUE(page.ok());
  ASSERT_EQ(page->jobs.size(), 2u);
  EXPECT_EQ(page->jobs[0].id, "c");
  EXPECT_EQ(page->jobs[1].id, "a");
  EXPECT_EQ(page->jobs[1].owner, "alice");
  EXPECT_EQ(store_->List(ListOptions())->jobs.size(), 3u);

  EXPECT_EQ(store_->Usage("alice")->active_jobs, 2u);
  Succeed(kT0 + 10, 1234);  // job a
  const OwnerUsage u = *store_->Usage("alice");
  EXPECT_EQ(u.active_jobs, 1u);
  EXPECT_EQ(u.result_bytes, 1234u);
  EXPECT_EQ(store_->Usage("bob")->result_bytes, 0u);
  EXPECT_EQ(store_->Usage("nobody")->active_jobs, 0u);
}

// A key is each principal's own: Bob's use of Alice's key is a first use,
// and makes a job of his own that names nothing of hers.
TEST_F(RetentionTest, ARequestIdOfAnotherPrincipalNamesNoJob) {
  NewJob job;
  job.id = "j-alice";
  job.spec = "s";
  job.request_id = "key";
  job.owner = "alice";
  ASSERT_TRUE(store_->Create(job, kT0).ok());
  job.id = "j-bob";
  job.owner = "bob";
  auto again = store_->Create(job, kT0);
  ASSERT_TRUE(again.ok()) << again.status();
  EXPECT_EQ(again->id, "j-bob");
  EXPECT_EQ(again->owner, "bob");
}

TEST_F(RetentionTest, DeleteRefusesActiveJobsAndRemovesFinishedOnes) {
  Create("a", "alice", kT0);
  EXPECT_EQ(store_->Delete("a").code(), absl::StatusCode::kFailedPrecondition);
  Succeed(kT0 + 5, 10);
  auto freed = results_->Delete("a");
  ASSERT_TRUE(freed.ok());
  EXPECT_EQ(*freed, 10u);
  EXPECT_TRUE(store_->Delete("a").ok());
  EXPECT_EQ(store_->Get("a").status().code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(store_->Delete("a").code(), absl::StatusCode::kNotFound);
}

TEST_F(RetentionTest, SweepExpiresOldUnpinnedResultsOnly) {
  Create("old", "alice", kT0);
  Create("pinned", "alice", kT0 + 1);
  Create("young", "alice", kT0 + 2);
  Succeed(kT0 + 10, 100);
  Succeed(kT0 + 20, 200);
  Succeed(kT0 + 5 * kHour, 300);
  ASSERT_TRUE(store_->SetPinned("pinned", true)->pinned);

  RetentionSweeper sweeper(store_.get(), results_.get(), nullptr, 24 * kHour, 1000);
  EXPECT_EQ(sweeper.SweepOnce(kT0 + 24 * kHour).results, 0);  // nothing is a day old yet
  const TimeMs later = kT0 + 24 * kHour + 1000;
  EXPECT_EQ(sweeper.SweepOnce(later).results, 1);
  auto old = store_->Get("old");
  EXPECT_EQ(old->result_expire_time, later);
  EXPECT_EQ(results_->Size("old").status().code(), absl::StatusCode::kNotFound);
  EXPECT_TRUE(results_->Size("pinned").ok());
  EXPECT_TRUE(results_->Size("young").ok());
  EXPECT_EQ(store_->Usage("alice")->result_bytes, 500u);  // expired bytes no longer count
  EXPECT_EQ(sweeper.SweepOnce(later).results, 0);         // once only

  // Unpinned, it goes with the next sweep.
  ASSERT_TRUE(store_->SetPinned("pinned", false).ok());
  EXPECT_EQ(sweeper.SweepOnce(later).results, 1);
  EXPECT_EQ(results_->Size("pinned").status().code(), absl::StatusCode::kNotFound);
}

TEST_F(RetentionTest, AssetsHaveOwnersAndUnusedOldOnesExpire) {
  const std::string used = Upload("bytes a queued job names", "alice");
  const std::string unused = Upload("bytes nobody names", "alice");
  Upload("bytes nobody names", "bob");  // the same bytes: stored once, two owners
  EXPECT_TRUE(assets_->IsOwner(unused, "alice"));
  EXPECT_TRUE(assets_->IsOwner(unused, "bob"));
  EXPECT_FALSE(assets_->IsOwner(used, "bob"));
  EXPECT_EQ(assets_->OwnedBytes("alice"), 24u + 18u);
  EXPECT_EQ(assets_->OwnedBytes("bob"), 18u);

  // A queued job that names `used` keeps it; the store lists its spec.
  v1::JobSpec spec;
  spec.mutable_set_ifs()
      ->add_maps()
      ->mutable_condensation()
      ->mutable_mesh()
      ->mutable_asset()
      ->set_sha256(used);
  NewJob job;
  job.id = "q";
  spec.SerializeToString(&job.spec);
  ASSERT_TRUE(store_->Create(job, kT0).ok());

  RetentionSweeper sweeper(store_.get(), results_.get(), assets_.get(), kHour, 1000);
  const TimeMs now = std::chrono::duration_cast<std::chrono::milliseconds>(
                         std::chrono::system_clock::now().time_since_epoch())
                         .count();
  EXPECT_EQ(sweeper.SweepOnce(now).assets, 0);  // uploaded just now
  EXPECT_EQ(sweeper.SweepOnce(now + 2 * kHour).assets, 1);
  EXPECT_EQ(assets_->Find(unused).status().code(), absl::StatusCode::kNotFound);
  EXPECT_FALSE(std::filesystem::exists(dir_ / "assets" / (unused + ".owners")));
  EXPECT_FALSE(std::filesystem::exists(dir_ / "assets" / (unused + ".names")));
  EXPECT_TRUE(assets_->Find(used).ok());
}

}  // namespace
}  // namespace nimbus::server
