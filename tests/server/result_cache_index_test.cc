// The result cache index's contract (ResultCacheIndex in server/job_store.h),
// the same on every store kind.
#include <gtest/gtest.h>

#include "server/job_store.h"
#include "tests/support/job_store_contract.h"

namespace nimbus::server {
namespace {

using namespace contract;  // NOLINT: the contract's helpers

NIMBUS_STORE_CONTRACT_SUITE(ResultCacheIndexTest);

TEST_P(ResultCacheIndexTest, FindCachedFindsTheNewestSucceededTopLevelJob) {
  EXPECT_FALSE(store().FindCached("h", "alice")->has_value());
  ASSERT_TRUE(store().Create(OwnedJob("old", 0, "h"), kT0).ok());
  ASSERT_TRUE(store().Create(OwnedJob("new", 0, "h"), kT0 + 1).ok());
  ASSERT_TRUE(store().Create(OwnedJob("other", 0, "g"), kT0 + 2).ok());
  EXPECT_FALSE(store().FindCached("h", "alice")->has_value());  // none finished
  EXPECT_EQ(Claim("w"), "old");
  Succeed("old", "w");
  EXPECT_EQ(Claim("w"), "new");
  Completion done;
  done.result_key = "new";
  ASSERT_TRUE(store().Complete("new", "w", done, kT0 + 50).ok());
  EXPECT_EQ((*store().FindCached("h", "alice"))->id, "new");
  EXPECT_FALSE(store().FindCached("h", "bob")->has_value());
  EXPECT_FALSE(store().FindCached("", "alice")->has_value());
  // Pinned or not does not matter; expired results are skipped.
  ASSERT_TRUE(store().SetPinned("new", true).ok());
  EXPECT_EQ((*store().FindCached("h", "alice"))->id, "new");
  ASSERT_TRUE(store().MarkResultExpired("new", kT0 + 60).ok());
  EXPECT_EQ((*store().FindCached("h", "alice"))->id, "old");
}

TEST_P(ResultCacheIndexTest, FindCachedIgnoresShards) {
  ASSERT_TRUE(store().Create(OwnedJob("p", 2, "h"), kT0).ok());
  const std::string first = Claim("w");
  Succeed(first, "w");
  EXPECT_FALSE(store().FindCached("h", "alice")->has_value());
}

TEST_P(ResultCacheIndexTest, ACacheHitIsCreatedSucceeded) {
  NewJob hit = OwnedJob("copy", 0, "h");
  hit.cached_from = "orig";
  hit.cached_result.result_key = "copy";
  hit.cached_result.result_size = 77;
  hit.cached_result.result_sha256 = "cd";
  auto r = store().Create(hit, kT0);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_EQ(r->state, JobState::kSucceeded);
  EXPECT_EQ(r->cached_from, "orig");
  EXPECT_EQ(r->result_key, "copy");
  EXPECT_EQ(r->result_size, 77u);
  EXPECT_EQ(r->result_sha256, "cd");
  EXPECT_EQ(r->end_time, kT0);
  EXPECT_EQ(r->progress_done, r->progress_total);
  EXPECT_EQ(Claim("w"), "");
  // It is itself a cache entry.
  EXPECT_EQ((*store().FindCached("h", "alice"))->id, "copy");
}

}  // namespace
}  // namespace nimbus::server
