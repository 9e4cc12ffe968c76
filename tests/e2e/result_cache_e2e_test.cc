// The result cache through a real nimbusd (docs/result_cache.md): once a
// spec has succeeded, resubmitting it is answered from the cache, and a
// spec that differs in any one top-level field (grid, output, image,
// detail, name) or inside its generator (chaos_game, set_ifs,
// fractal_field, explore) is not.
#include <gtest/gtest.h>

#include <map>

#include "tests/support/server_fixture.h"
#include "tests/support/spec_variants.h"

namespace nimbus {
namespace {

class ResultCacheE2E : public testing::NimbusdTest {
 protected:
  // Runs `base` to its end (once per base), checks that resubmitting it
  // hits the cache, then that `changed` misses; the miss is cancelled.
  void ExpectMiss(const testing::SpecChange& c) {
    SCOPED_TRACE(c.field);
    const std::string key = c.base.SerializeAsString();
    if (!first_.count(key)) {
      auto job = client_->Submit(c.base);
      ASSERT_TRUE(job.ok()) << job.status();
      auto done = client_->Watch(job->id(), {}, [](const v1::WatchJobResponse&) {});
      ASSERT_TRUE(done.ok()) << done.status();
      ASSERT_EQ(done->state(), v1::JOB_STATE_SUCCEEDED) << done->error();
      first_[key] = done->id();
      auto hit = client_->Submit(c.base);
      ASSERT_TRUE(hit.ok()) << hit.status();
      EXPECT_EQ(hit->state(), v1::JOB_STATE_SUCCEEDED);
      EXPECT_EQ(hit->cached_from(), done->id()) << "the same spec must hit the cache";
    }
    auto miss = client_->Submit(c.changed);
    ASSERT_TRUE(miss.ok()) << miss.status();
    EXPECT_EQ(miss->cached_from(), "") << "a changed " << c.field << " was answered from the cache";
    EXPECT_NE(miss->state(), v1::JOB_STATE_SUCCEEDED);
    (void)client_->Cancel(miss->id());
  }

  std::map<std::string, std::string> first_;  // base spec bytes -> its first job
};

TEST_F(ResultCacheE2E, AChangeInAnyTopLevelFieldMisses) {
  for (const testing::SpecChange& c : testing::TopLevelSpecChanges())
    if (c.base.has_chaos_game()) ExpectMiss(c);
}

TEST_F(ResultCacheE2E, AChangeInsideEachGeneratorMisses) {
  for (const testing::SpecChange& c : testing::TopLevelSpecChanges())
    if (!c.base.has_chaos_game() && !c.base.has_jelly()) ExpectMiss(c);
}

}  // namespace
}  // namespace nimbus
