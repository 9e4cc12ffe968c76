// Bounds on stored and sent text: cut on a character boundary with a marker
// naming the original size, always valid UTF-8.
#include "server/bounded_text.h"

#include <gtest/gtest.h>

#include <string>

namespace nimbus::server {
namespace {

TEST(BoundText, ShortTextIsUnchanged) {
  EXPECT_EQ(BoundText("grid: bad value\n\tsecond line", 4096), "grid: bad value\n\tsecond line");
  EXPECT_EQ(BoundText("", 10), "");
}

TEST(BoundText, LongTextIsCutWithTheOriginalSize) {
  const std::string huge(64 << 20, 'x');
  const std::string cut = BoundText(huge, 4096);
  EXPECT_EQ(cut.substr(0, 4096), std::string(4096, 'x'));
  EXPECT_EQ(cut.substr(4096), "\xe2\x80\xa6 [truncated, 67108864 bytes]");
}

TEST(BoundText, NeverSplitsACharacterOrKeepsBadBytes) {
  // "é" is two bytes: a cut after 3 bytes keeps "aé" only.
  EXPECT_EQ(BoundText("a\xc3\xa9\xc3\xa9", 4), "a\xc3\xa9\xe2\x80\xa6 [truncated, 5 bytes]");
  // Invalid UTF-8 and control bytes become '?', so protobuf strings stay valid.
  EXPECT_EQ(BoundText(std::string("ok\xff\xc3(\x01z", 7), 100), "ok??" "(?z");  // split: "??(" is a trigraph
  EXPECT_EQ(BoundText("\xed\xa0\x80", 100), "???");  // a UTF-16 surrogate
}

TEST(EchoId, LongIdsAreCut) {
  EXPECT_EQ(EchoId("j-0123456789abcdef"), "j-0123456789abcdef");
  const std::string echoed = EchoId(std::string(100'000, 'i'));
  EXPECT_EQ(echoed, std::string(kMaxEchoedIdBytes, 'i') + "\xe2\x80\xa6");
}

}  // namespace
}  // namespace nimbus::server
