// The result cache's key (docs/result_cache.md): a change in any top-level
// JobSpec field, or inside any generator, gives another spec hash; only
// `shards` and `no_cache` are left out. Every field of JobSpec must be
// named here, so a new field cannot escape the key unnoticed.
#include <gtest/gtest.h>

#include <set>
#include <string>

#include "proto/spec_convert.h"
#include "tests/support/spec_variants.h"

namespace nimbus::spec {
namespace {

TEST(SpecHash, EveryTopLevelFieldChangesTheKey) {
  std::set<std::string> covered;
  for (const testing::SpecChange& c : testing::TopLevelSpecChanges()) {
    SCOPED_TRACE(c.field);
    // Both sides are real specs, so the cache could meet them.
    EXPECT_TRUE(ConvertSpec(c.base, {}).ok()) << ConvertSpec(c.base, {}).status();
    EXPECT_TRUE(ConvertSpec(c.changed, {}).ok()) << ConvertSpec(c.changed, {}).status();
    EXPECT_EQ(SpecHash(c.base), SpecHash(v1::JobSpec(c.base)));
    EXPECT_NE(SpecHash(c.base), SpecHash(c.changed));
    EXPECT_EQ(SpecHash(c.base).size(), 64u);
    covered.insert(c.field);
  }
  const std::set<std::string> left_out = {"shards", "no_cache"};
  const google::protobuf::Descriptor* d = v1::JobSpec::descriptor();
  for (int i = 0; i < d->field_count(); ++i) {
    const std::string name = d->field(i)->name();
    EXPECT_TRUE(covered.count(name) || left_out.count(name))
        << "JobSpec." << name << " has no case in testing::TopLevelSpecChanges()";
  }
}

TEST(SpecHash, ShardsAndNoCacheAreNotPartOfTheKey) {
  const v1::JobSpec base = testing::SmallChaosGame();
  v1::JobSpec sharded = base, uncached = base;
  sharded.set_shards(4);
  uncached.set_no_cache(true);
  EXPECT_EQ(SpecHash(base), SpecHash(sharded));
  EXPECT_EQ(SpecHash(base), SpecHash(uncached));
}

}  // namespace
}  // namespace nimbus::spec
