// The poke store's contract (PokeStore in server/job_store.h), the same on
// every store kind.
#include <gtest/gtest.h>

#include "absl/status/status.h"
#include "server/job_store.h"
#include "tests/support/job_store_contract.h"

namespace nimbus::server {
namespace {

using namespace contract;  // NOLINT: the contract's helpers

NIMBUS_STORE_CONTRACT_SUITE(PokeStoreTest);

TEST_P(PokeStoreTest, PokesNeedARunningJob) {
  EXPECT_EQ(store_->AddPoke("nope", Push(0, 1)).status().code(), absl::StatusCode::kNotFound);
  CreateOrDie(*store_, "a", kT0);
  auto queued = store_->AddPoke("a", Push(0, 1));
  EXPECT_EQ(queued.status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_NE(queued.status().message().find("QUEUED"), std::string::npos);
  ASSERT_TRUE(store_->ClaimNext("w", kT0, 1000).ok());
  auto ok = store_->AddPoke("a", Push(0, 1));
  ASSERT_TRUE(ok.ok()) << ok.status();
  EXPECT_EQ(ok->frame, -1);
  EXPECT_GT(ok->seq, 0);
}

TEST_P(PokeStoreTest, TakingPokesFixesTheirFrameForEveryLaterAttempt) {
  CreateOrDie(*store_, "a", kT0);
  ASSERT_TRUE(store_->ClaimNext("w1", kT0, 1000).ok());
  PokeRecord drag = Push(2, 0.5);
  drag.drag = true;
  drag.y = -1;
  drag.z = 2;
  drag.drag_stiffness = 80;
  drag.drag_frames = 3;
  ASSERT_TRUE(store_->AddPoke("a", Push(1, 3)).ok());
  ASSERT_TRUE(store_->AddPoke("a", drag).ok());
  // Another worker cannot take them.
  EXPECT_EQ(store_->TakePokes("a", "intruder", 4).status().code(),
            absl::StatusCode::kFailedPrecondition);
  auto at4 = store_->TakePokes("a", "w1", 4);
  ASSERT_TRUE(at4.ok()) << at4.status();
  ASSERT_EQ(at4->size(), 2u);
  EXPECT_EQ((*at4)[0].body, 1);
  EXPECT_EQ((*at4)[0].x, 3);
  EXPECT_EQ((*at4)[0].frame, 4);
  const PokeRecord& d = (*at4)[1];
  EXPECT_TRUE(d.drag);
  EXPECT_EQ(d.body, 2);
  EXPECT_EQ(d.x, 0.5);
  EXPECT_EQ(d.y, -1);
  EXPECT_EQ(d.z, 2);
  EXPECT_EQ(d.drag_stiffness, 80);
  EXPECT_EQ(d.drag_frames, 3u);
  EXPECT_LT((*at4)[0].seq, d.seq);
  EXPECT_TRUE(store_->TakePokes("a", "w1", 5)->empty());
  // A later poke goes to the next frame taken; the job restarts and a new
  // attempt sees each poke at its own frame again.
  ASSERT_TRUE(store_->AddPoke("a", Push(0, 7)).ok());
  ASSERT_EQ(store_->TakePokes("a", "w1", 6)->size(), 1u);
  ASSERT_TRUE(store_->Release("a", "w1").ok());
  ASSERT_TRUE(store_->ClaimNext("w2", kT0 + 1, 1000).ok());
  EXPECT_EQ(store_->TakePokes("a", "w2", 4)->size(), 2u);
  EXPECT_TRUE(store_->TakePokes("a", "w2", 5)->empty());
  auto at6 = store_->TakePokes("a", "w2", 6);
  ASSERT_EQ(at6->size(), 1u);
  EXPECT_EQ((*at6)[0].x, 7);
}

}  // namespace
}  // namespace nimbus::server
