// nimbusd's JSON log lines: the expected lines are written out by hand, and
// every line must parse as JSON with protobuf's own parser.
#include "server/json_log.h"

#include <gtest/gtest.h>

#include "google/protobuf/struct.pb.h"
#include "google/protobuf/util/json_util.h"

namespace nimbus::server {
namespace {

bool ParsesAsJson(const std::string& line) {
  google::protobuf::Struct s;
  return google::protobuf::util::JsonStringToMessage(line, &s).ok();
}

TEST(JsonLog, PairsBecomeMembersJobAndEventAtTheTop) {
  const std::string line = LogLineJson(
      "2026-11-29T02:38:09.273Z", "info", "vm-1",
      R"(job=j-42 event=submitted name=tree owner=alice work=200000000 pinned=true)");
  EXPECT_EQ(line,
            R"({"time":"2026-11-29T02:38:09.273Z","level":"info","replica":"vm-1",)"
            R"("job":"j-42","event":"submitted","fields":{"name":"tree","owner":"alice",)"
            R"("work":200000000,"pinned":true}})");
  EXPECT_TRUE(ParsesAsJson(line));
}

TEST(JsonLog, QuotedValuesEscapesAndFreeText) {
  const std::string line =
      LogLineJson("t", "warn", "r", "listening on 127.0.0.1:5 event=x reason=\"disk \\\"full\\\" at\t/x\" n=007");
  EXPECT_EQ(line, R"({"time":"t","level":"warn","replica":"r","event":"x",)"
                  R"("message":"listening on 127.0.0.1:5","fields":{"reason":"disk \"full\" at\t/x",)"
                  R"("n":"007"}})");
  EXPECT_TRUE(ParsesAsJson(line));
}

TEST(JsonLog, BytesThatAreNotUtf8AndControlsStayValidJson) {
  const std::string name = std::string("a\xff\xfe") + "\x01" + "\xc3\xa9" + "\\x";
  const std::string line = LogLineJson("t", "info", "r", "event=e name=\"" + name + "\"");
  EXPECT_EQ(line, R"({"time":"t","level":"info","replica":"r","event":"e",)"
                  R"("fields":{"name":"a\ufffd\ufffd\u0001)"
                  "\xc3\xa9"
                  R"(\\x"}})");
  EXPECT_TRUE(ParsesAsJson(line));
}

}  // namespace
}  // namespace nimbus::server
