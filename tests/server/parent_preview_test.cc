// Watchers of a sharded job see previews that cover every shard: the pool
// sums each shard's newest coarse counts, replacing a shard's older counts.
#include <gtest/gtest.h>

#include "server/job_hub.h"
#include "server/job_store.h"
#include "server/result_store.h"
#include "server/worker_pool.h"
#include "tests/support/test_util.h"

namespace nimbus::server {
namespace {

CountGrid Counts(uint32_t at_origin, uint32_t at_corner) {
  CountGrid g({4, 4, 4});
  g.Add(0, 0, 0, at_origin);
  g.Add(3, 3, 3, at_corner);
  return g;
}

TEST(ParentPreview, SumsTheNewestCountsOfEveryShard) {
  testing::TempDir dir;
  auto store = OpenSqliteJobStore((dir / "jobs.db").string());
  ASSERT_TRUE(store.ok()) << store.status();
  auto results = OpenLocalResultStore(dir / "results");
  ASSERT_TRUE(results.ok()) << results.status();
  JobHub hub;
  WorkerPool pool(store->get(), results->get(), &hub, WorkerOptions{});

  auto [one, seq1] = pool.SumParentPreview("p", 0, 16, Counts(2, 0));
  EXPECT_EQ(one.Get(0, 0, 0), 2u);
  EXPECT_EQ(seq1, 1u);
  auto [two, seq2] = pool.SumParentPreview("p", 2, 16, Counts(3, 5));
  EXPECT_EQ(two.Get(0, 0, 0), 5u);
  EXPECT_EQ(two.Get(3, 3, 3), 5u);
  EXPECT_EQ(seq2, 2u);
  // Shard 0 ran on: its newer counts replace its older ones.
  auto [three, seq3] = pool.SumParentPreview("p", 0, 16, Counts(7, 1));
  EXPECT_EQ(three.Get(0, 0, 0), 10u);
  EXPECT_EQ(three.Get(3, 3, 3), 6u);
  EXPECT_EQ(seq3, 3u);
  // Another resolution and another parent are kept apart.
  auto [other, seq_other] = pool.SumParentPreview("q", 0, 16, Counts(1, 1));
  EXPECT_EQ(other.Get(0, 0, 0), 1u);
  EXPECT_EQ(seq_other, 1u);
  auto [coarser, seq4] = pool.SumParentPreview("p", 1, 8, Counts(4, 0));
  EXPECT_EQ(coarser.Get(0, 0, 0), 4u);
  EXPECT_EQ(seq4, 4u);
}

}  // namespace
}  // namespace nimbus::server
