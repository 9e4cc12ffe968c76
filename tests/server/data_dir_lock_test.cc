// One server per SQLite data dir: a second one is refused with a message
// that names the folder and the holder, and the lock goes with its holder.
#include "server/data_dir_lock.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <string>

#include "server/server.h"
#include "tests/support/test_util.h"

namespace nimbus::server {
namespace {

TEST(DataDirLock, SecondHolderIsRefusedUntilTheFirstLetsGo) {
  testing::TempDir dir;
  {
    auto first = DataDirLock::Acquire(dir.path());
    ASSERT_TRUE(first.ok()) << first.status();
    auto second = DataDirLock::Acquire(dir.path());
    ASSERT_FALSE(second.ok());
    EXPECT_TRUE(absl::IsFailedPrecondition(second.status()));
    const std::string message(second.status().message());
    EXPECT_NE(message.find(dir.path().string()), std::string::npos) << message;
    EXPECT_NE(message.find("(pid " + std::to_string(::getpid()) + ")"), std::string::npos)
        << message;
  }
  EXPECT_TRUE(DataDirLock::Acquire(dir.path()).ok());
}

TEST(DataDirLock, ASecondServerOnTheSameDataDirIsRefused) {
  testing::TempDir dir;
  ServerOptions o;
  o.listen = "";
  o.data_dir = dir / "data";
  auto first = NimbusServer::Start(o);
  ASSERT_TRUE(first.ok()) << first.status();
  auto second = NimbusServer::Start(o);
  ASSERT_FALSE(second.ok());
  EXPECT_NE(second.status().message().find("is in use by another Nimbus server"),
            std::string::npos)
      << second.status();
  first->reset();
  EXPECT_TRUE(NimbusServer::Start(o).ok());
}

}  // namespace
}  // namespace nimbus::server
