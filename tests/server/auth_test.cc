// Tokens and principals: the file format, its errors, authentication of the
// authorization metadata, and which listen addresses count as loopback.
#include "server/auth.h"

#include <gtest/gtest.h>
#include <sys/stat.h>

#include <fstream>

#include "tests/support/test_util.h"

namespace nimbus::server {
namespace {

constexpr char kTokens[] =
    "# comment\n"
    "\n"
    "  alice-token-0123456789   alice \n"
    "root-token-0123456789abc root admin\n";

TEST(TokenTable, ParsesPrincipalsAndTheAdminRole) {
  auto table = TokenTable::Parse(kTokens, "test");
  ASSERT_TRUE(table.ok()) << table.status();
  EXPECT_EQ(table->size(), 2u);
  auto alice = table->Authenticate("Bearer alice-token-0123456789");
  ASSERT_TRUE(alice.ok());
  EXPECT_EQ(alice->name, "alice");
  EXPECT_FALSE(alice->admin);
  auto root = table->Authenticate("Bearer root-token-0123456789abc");
  ASSERT_TRUE(root.ok());
  EXPECT_EQ(root->name, "root");
  EXPECT_TRUE(root->admin);
  // Entries may also be separated by ';' (the environment variable).
  EXPECT_EQ(TokenTable::Parse("aaaaaaaaaaaaaaaa a; bbbbbbbbbbbbbbbb b admin", "env")->size(), 2u);
}

TEST(TokenTable, RefusesMissingWrongAndMalformedTokens) {
  auto table = *TokenTable::Parse(kTokens, "test");
  auto none = table.Authenticate(std::nullopt);
  EXPECT_EQ(none.status().code(), absl::StatusCode::kUnauthenticated);
  EXPECT_NE(none.status().message().find("requires a token"), std::string::npos);
  auto wrong = table.Authenticate("Bearer alice-token-0123456780");
  EXPECT_EQ(wrong.status().code(), absl::StatusCode::kUnauthenticated);
  EXPECT_EQ(wrong.status().message(), "unknown token");
  auto basic = table.Authenticate("Basic alice-token-0123456789");
  EXPECT_EQ(basic.status().code(), absl::StatusCode::kUnauthenticated);
  EXPECT_EQ(table.Authenticate("Bearer ").status().code(), absl::StatusCode::kUnauthenticated);
}

TEST(TokenTable, WithoutTokensEveryCallerIsTheAnonymousAdmin) {
  TokenTable empty;
  auto p = empty.Authenticate(std::nullopt);
  ASSERT_TRUE(p.ok());
  EXPECT_EQ(p->name, "anonymous");
  EXPECT_TRUE(p->admin);
}

TEST(TokenTable, FileErrorsNameTheEntryNeverTheToken) {
  auto short_token = TokenTable::Parse("short alice\n", "tokens");
  EXPECT_EQ(short_token.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(short_token.status().message(), "tokens entry 1: token is shorter than 16 characters");
  auto bad_role = TokenTable::Parse("# x\nsecret-token-0123456789 alice root\n", "tokens");
  EXPECT_NE(bad_role.status().message().find("tokens entry 2"), std::string::npos);
  EXPECT_EQ(bad_role.status().message().find("secret-token"), std::string::npos);
  auto twice = TokenTable::Parse("same-token-0123456789 a\nsame-token-0123456789 b\n", "t");
  EXPECT_NE(twice.status().message().find("used twice"), std::string::npos);
  EXPECT_EQ(TokenTable::Parse("# nothing\n", "t").status().code(),
            absl::StatusCode::kInvalidArgument);
}

TEST(TokenTable, AFileOthersMayReadIsRefused) {
  testing::TempDir dir;
  const auto path = dir / "tokens";
  std::ofstream(path) << kTokens;
  ::chmod(path.c_str(), 0640);
  auto open = ReadTokensFile(path.string());
  EXPECT_EQ(open.status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_NE(open.status().message().find("mode 640"), std::string::npos) << open.status();
  ::chmod(path.c_str(), 0600);
  auto text = ReadTokensFile(path.string());
  ASSERT_TRUE(text.ok()) << text.status();
  EXPECT_EQ(*text, kTokens);
  EXPECT_EQ(ReadTokensFile((dir / "missing").string()).status().code(),
            absl::StatusCode::kNotFound);
}

TEST(Loopback, OnlyAddressesThisHostAloneReaches) {
  EXPECT_TRUE(IsLoopbackListen("127.0.0.1:50051"));
  EXPECT_TRUE(IsLoopbackListen("127.1.2.3:0"));
  EXPECT_TRUE(IsLoopbackListen("localhost:80"));
  EXPECT_TRUE(IsLoopbackListen("[::1]:50051"));
  EXPECT_TRUE(IsLoopbackListen("unix:/run/nimbus.sock"));
  EXPECT_FALSE(IsLoopbackListen("0.0.0.0:50051"));
  EXPECT_FALSE(IsLoopbackListen("[::]:50051"));
  EXPECT_FALSE(IsLoopbackListen("10.0.0.5:50051"));
  EXPECT_FALSE(IsLoopbackListen("nimbus.example.com:50051"));
}

TEST(ConstantTimeEquals, ComparesWholeStrings) {
  EXPECT_TRUE(ConstantTimeEquals("abc", "abc"));
  EXPECT_FALSE(ConstantTimeEquals("abc", "abd"));
  EXPECT_FALSE(ConstantTimeEquals("abc", "ab"));
}

}  // namespace
}  // namespace nimbus::server
